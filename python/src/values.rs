//! The two values the package passes around: [`Spikes`] (bit-packed planes and their clock) and
//! [`Events`] (four columns and their sensor), each holding numpy arrays that were Rust vectors,
//! and the conversions of what a user passes in their place.

use ndarray::{Array3, ArrayView2, ArrayView3};
use numpy::{
    Element, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PySlice;

use neuspike_representations::EventSlice;
use neuspike_schemas::{EventBatch, SpikeChunk, bytes_per_plane, pack_planes, unpack_planes_into};

use crate::{errors, threads};

/// Spike planes, bit-packed as the camera sends them, with their clock.
///
/// ``packed`` is ``uint8 [N, ceil(H * W / 8)]``: pixel ``i = y * W + x`` of plane ``k`` is bit
/// ``i % 8`` (least significant first) of byte ``i // 8`` of row ``k``, rows top-down, as
/// ``numpy.unpackbits(packed, axis=1, bitorder="little")[:, :H * W]`` reads it. Plane ``k`` is
/// stamped ``t_first_ns + k * plane_period_ns`` and carries the light of the tick before it.
/// Every kernel takes a ``Spikes`` or unpacked planes ``[N, H, W]`` (``uint8`` or ``bool``,
/// nonzero = spike) alike.
#[pyclass(module = "neuspike", frozen)]
pub struct Spikes {
    /// Plane width in pixels.
    #[pyo3(get)]
    width: usize,
    /// Plane height in pixels.
    #[pyo3(get)]
    height: usize,
    /// Index of the first plane in its recording or simulation.
    #[pyo3(get)]
    first_plane: u64,
    /// Time stamp of the first plane, ns.
    #[pyo3(get)]
    t_first_ns: i64,
    /// Time between planes, ns (> 0).
    #[pyo3(get)]
    plane_period_ns: i64,
    /// Luminance per unit firing rate, where the source knows it (the simulator does).
    #[pyo3(get)]
    lum_per_rate: Option<f64>,
    packed: Py<PyArray2<u8>>,
}

/// The clock and shape of a [`Spikes`] apart from its planes.
#[derive(Clone, Copy, Debug)]
pub struct Clock {
    pub width: usize,
    pub height: usize,
    pub first_plane: u64,
    pub t_first_ns: i64,
    pub plane_period_ns: i64,
    pub lum_per_rate: Option<f64>,
}

impl Spikes {
    /// A chunk's planes, handed to numpy without a copy.
    pub fn from_chunk(py: Python<'_>, chunk: SpikeChunk) -> PyResult<Spikes> {
        let per = bytes_per_plane(chunk.width, chunk.height);
        let clock = Clock {
            width: chunk.width,
            height: chunk.height,
            first_plane: chunk.first_plane,
            t_first_ns: chunk.t_first_ns,
            plane_period_ns: chunk.plane_period_ns,
            lum_per_rate: chunk.lum_per_rate,
        };
        Self::from_bits(py, chunk.bits, chunk.n_planes, per, clock)
    }

    /// `n` packed planes of `per` bytes, handed to numpy without a copy.
    pub fn from_bits(
        py: Python<'_>,
        bits: Vec<u8>,
        n: usize,
        per: usize,
        clock: Clock,
    ) -> PyResult<Spikes> {
        clock.check(n)?;
        if bits.len() != n * per {
            return Err(errors::input(format!(
                "spikes: {} bytes are not {n} planes of {per}",
                bits.len()
            )));
        }
        let array = PyArray1::from_vec(py, bits).reshape([n, per])?;
        Ok(Self::with_array(array.unbind(), clock))
    }

    fn with_array(packed: Py<PyArray2<u8>>, c: Clock) -> Spikes {
        Spikes {
            width: c.width,
            height: c.height,
            first_plane: c.first_plane,
            t_first_ns: c.t_first_ns,
            plane_period_ns: c.plane_period_ns,
            lum_per_rate: c.lum_per_rate,
            packed,
        }
    }

    pub fn clock(&self) -> Clock {
        Clock {
            width: self.width,
            height: self.height,
            first_plane: self.first_plane,
            t_first_ns: self.t_first_ns,
            plane_period_ns: self.plane_period_ns,
            lum_per_rate: self.lum_per_rate,
        }
    }

    /// The packed planes, borrowed for reading.
    pub fn bits<'py>(&self, py: Python<'py>) -> PyReadonlyArray2<'py, u8> {
        self.packed.bind(py).readonly()
    }

    pub fn planes(&self, py: Python<'_>) -> usize {
        self.packed.bind(py).shape()[0]
    }
}

/// The most pixels a side of a plane or a sensor may have (the formats' 16-bit coordinates).
pub const MAX_SIDE: usize = 65_535;

impl Clock {
    /// Checks the clock of `n` planes: sides in `1..=`[`MAX_SIDE`], a period `> 0`, and every
    /// plane's number and time stamp within their integers.
    pub fn check(&self, n: usize) -> PyResult<()> {
        let (w, h) = (self.width, self.height);
        if !(1..=MAX_SIDE).contains(&w) || !(1..=MAX_SIDE).contains(&h) {
            return Err(errors::input(format!(
                "spikes: planes of {w}x{h}: each side must be 1..={MAX_SIDE}"
            )));
        }
        if self.plane_period_ns <= 0 {
            return Err(errors::input(format!(
                "plane_period_ns = {}: must be > 0",
                self.plane_period_ns
            )));
        }
        let last = (n as i64)
            .checked_mul(self.plane_period_ns)
            .and_then(|d| d.checked_add(self.t_first_ns))
            .and_then(|t| t.checked_sub(self.plane_period_ns));
        if last.is_none() || self.first_plane.checked_add(n as u64).is_none() {
            return Err(errors::input(format!(
                "t_first_ns = {}, plane_period_ns = {}, first_plane = {}: {n} planes run past a 64-bit clock",
                self.t_first_ns, self.plane_period_ns, self.first_plane
            )));
        }
        Ok(())
    }
}

#[pymethods]
impl Spikes {
    /// Wraps packed planes ``uint8 [N, ceil(H * W / 8)]`` (read in place when C-contiguous).
    #[new]
    #[pyo3(signature = (packed, width, height, *, t_first_ns = 0, plane_period_ns = 50_000, first_plane = 0, lum_per_rate = None))]
    fn new(
        py: Python<'_>,
        packed: &Bound<'_, PyAny>,
        width: usize,
        height: usize,
        t_first_ns: i64,
        plane_period_ns: i64,
        first_plane: u64,
        lum_per_rate: Option<f64>,
    ) -> PyResult<Spikes> {
        let array = contiguous(py, packed, "uint8")?;
        let array = array.cast_into::<PyArray2<u8>>().map_err(|_| {
            errors::input("packed: expected a 2-D uint8 array [N, ceil(H * W / 8)]")
        })?;
        let clock = Clock {
            width,
            height,
            first_plane,
            t_first_ns,
            plane_period_ns,
            lum_per_rate,
        };
        let shape = array.shape().to_vec();
        clock.check(shape[0])?;
        let per = bytes_per_plane(width, height);
        if shape[1] != per {
            return Err(errors::input(format!(
                "packed: expected shape [N, {per}] for {width}x{height} planes, got {shape:?}"
            )));
        }
        Ok(Spikes::with_array(array.unbind(), clock))
    }

    /// Packs unpacked planes ``[N, H, W]`` (``uint8`` or ``bool``, nonzero = spike).
    #[staticmethod]
    #[pyo3(signature = (planes, *, t_first_ns = 0, plane_period_ns = 50_000, first_plane = 0, lum_per_rate = None))]
    fn from_planes(
        py: Python<'_>,
        planes: &Bound<'_, PyAny>,
        t_first_ns: i64,
        plane_period_ns: i64,
        first_plane: u64,
        lum_per_rate: Option<f64>,
    ) -> PyResult<Spikes> {
        let planes = planes_in(planes)?;
        let view = view3(&planes)?;
        let (n, height, width) = view.dim();
        let clock = Clock {
            width,
            height,
            first_plane,
            t_first_ns,
            plane_period_ns,
            lum_per_rate,
        };
        // Refused before the planes are packed.
        clock.check(n)?;
        let bits = threads::run(py, || pack_planes(view))?;
        Spikes::from_bits(py, bits, n, bytes_per_plane(width, height), clock)
    }

    /// The packed planes ``uint8 [N, ceil(H * W / 8)]`` (the array itself, not a copy).
    #[getter]
    fn packed<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<u8>> {
        self.packed.bind(py).clone()
    }

    /// Number of planes.
    #[getter]
    fn n_planes(&self, py: Python<'_>) -> usize {
        self.planes(py)
    }

    fn __len__(&self, py: Python<'_>) -> usize {
        self.planes(py)
    }

    /// The planes unpacked, ``uint8 [N, H, W]``, 1 where a pixel fired.
    fn unpack<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let bits = self.bits(py);
        let bits = bits.as_slice().map_err(errors::input)?;
        let (n, h, w) = (self.planes(py), self.height, self.width);
        let planes = threads::run(py, || {
            let mut planes = Array3::<u8>::zeros((n, h, w));
            unpack_planes_into(bits, planes.view_mut());
            planes
        })?;
        to_numpy(py, planes)
    }

    /// Each plane's time stamp, ``int64 [N]`` ns.
    fn plane_times_ns<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        let times: Vec<i64> = (0..self.planes(py) as i64)
            .map(|k| {
                self.t_first_ns
                    .saturating_add(k.saturating_mul(self.plane_period_ns))
            })
            .collect();
        PyArray1::from_vec(py, times)
    }

    /// Planes ``start`` to ``stop`` (Python slice bounds), sharing this value's memory.
    fn window(&self, py: Python<'_>, start: isize, stop: isize) -> PyResult<Spikes> {
        let n = self.planes(py);
        let (a, b) = (
            clamp_index(start, n),
            clamp_index(stop, n).max(clamp_index(start, n)),
        );
        let slice = PySlice::new(py, a as isize, b as isize, 1);
        let view = self
            .packed
            .bind(py)
            .get_item(slice)?
            .cast_into::<PyArray2<u8>>()
            .map_err(|e| errors::input(e.to_string()))?;
        let mut clock = self.clock();
        clock.first_plane = self.first_plane.saturating_add(a as u64);
        clock.t_first_ns = self
            .t_first_ns
            .saturating_add((a as i64).saturating_mul(self.plane_period_ns));
        Ok(Spikes::with_array(view.unbind(), clock))
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Spikes({} planes of {}x{}, first plane {}, t_first_ns={}, plane_period_ns={})",
            self.planes(py),
            self.width,
            self.height,
            self.first_plane,
            self.t_first_ns,
            self.plane_period_ns
        )
    }
}

/// A Python index as Python slices read it: negative from the end, clamped to `0..=n`.
fn clamp_index(i: isize, n: usize) -> usize {
    if i < 0 {
        n.saturating_sub(i.unsigned_abs())
    } else {
        (i as usize).min(n)
    }
}

/// `numpy.ascontiguousarray(obj, dtype)`: the array itself when it already is one.
pub fn contiguous<'py>(
    py: Python<'py>,
    obj: &Bound<'py, PyAny>,
    dtype: &str,
) -> PyResult<Bound<'py, PyAny>> {
    py.import("numpy")?
        .call_method1("ascontiguousarray", (obj, dtype))
}

/// Unpacked planes `[N, H, W]` of `uint8` (read in place when C-contiguous) or `bool`
/// (converted).
pub fn planes_in<'py>(obj: &Bound<'py, PyAny>) -> PyResult<PyReadonlyArray3<'py, u8>> {
    let dtype = obj
        .getattr("dtype")
        .and_then(|d| d.str())
        .map(|d| d.to_string())
        .unwrap_or_default();
    let ndim = obj.getattr("ndim").and_then(|n| n.extract::<usize>()).ok();
    if (dtype == "uint8" || dtype == "bool") && ndim == Some(3) {
        return contiguous(obj.py(), obj, "uint8")?
            .extract::<PyReadonlyArray3<'py, u8>>()
            .map_err(|e| errors::input(e.to_string()));
    }
    Err(errors::input(format!(
        "spikes: expected neuspike.Spikes or planes [N, H, W] of uint8 or bool, got {}",
        describe(obj)
    )))
}

/// A C-contiguous numpy array as this workspace's ndarray view.
pub fn view2<'a, T: Element>(a: &'a PyReadonlyArray2<'_, T>) -> PyResult<ArrayView2<'a, T>> {
    let s = a.shape();
    ArrayView2::from_shape((s[0], s[1]), a.as_slice().map_err(errors::input)?)
        .map_err(errors::input)
}

/// A C-contiguous numpy array as this workspace's ndarray view.
pub fn view3<'a, T: Element>(a: &'a PyReadonlyArray3<'_, T>) -> PyResult<ArrayView3<'a, T>> {
    let s = a.shape();
    ArrayView3::from_shape((s[0], s[1], s[2]), a.as_slice().map_err(errors::input)?)
        .map_err(errors::input)
}

/// A frame argument: any array-like of two dimensions, as `float32` (read in place where it is
/// one and C-contiguous).
pub fn frame_in<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<PyReadonlyArray2<'py, f32>> {
    contiguous(obj.py(), obj, "float32")?
        .extract::<PyReadonlyArray2<'py, f32>>()
        .map_err(|_| {
            errors::input(format!(
                "{name}: expected a 2-D array of luminance, got {}",
                describe(obj)
            ))
        })
}

/// Arrays of one shape stacked along a new first axis, on the pool with the GIL released; none
/// give an empty array.
pub fn stack_on_pool<D: ndarray::Dimension>(
    py: Python<'_>,
    items: &[ndarray::ArrayView<'_, f32, D>],
) -> PyResult<ndarray::Array<f32, D::Larger>> {
    if items.is_empty() {
        let ndim = D::NDIM.map_or(1, |n| n + 1);
        return Ok(ndarray::Array::zeros(
            <D::Larger as ndarray::Dimension>::zeros(ndim),
        ));
    }
    threads::run(py, || ndarray::stack(ndarray::Axis(0), items))?.map_err(errors::input)
}

/// An array made here handed to numpy without a copy: its vector, reshaped.
pub fn to_numpy<T: Element + Clone, D: ndarray::Dimension>(
    py: Python<'_>,
    a: ndarray::Array<T, D>,
) -> PyResult<Bound<'_, PyAny>> {
    let shape = a.shape().to_vec();
    let v = if a.is_standard_layout() {
        match a.into_raw_vec_and_offset() {
            (v, None | Some(0)) => v,
            (v, Some(off)) => v[off..].to_vec(),
        }
    } else {
        a.iter().cloned().collect()
    };
    Ok(PyArray1::from_vec(py, v).reshape(shape)?.into_any())
}

/// What a value is, for an error message: an array's dtype and shape, or its type.
pub fn describe(obj: &Bound<'_, PyAny>) -> String {
    match (obj.getattr("dtype"), obj.getattr("shape")) {
        (Ok(d), Ok(s)) => format!("an array of {d} with shape {s}"),
        _ => obj
            .get_type()
            .name()
            .map_or_else(|_| "a value".into(), |n| format!("a {n}")),
    }
}

/// Spikes as a kernel takes them: packed (a [`Spikes`]) or unpacked planes.
pub enum SpikesIn<'py> {
    Packed {
        bits: PyReadonlyArray2<'py, u8>,
        n: usize,
        height: usize,
        width: usize,
    },
    Planes(PyReadonlyArray3<'py, u8>),
}

impl SpikesIn<'_> {
    /// `(N, H, W)`.
    pub fn dim(&self) -> (usize, usize, usize) {
        match self {
            SpikesIn::Packed {
                n, height, width, ..
            } => (*n, *height, *width),
            SpikesIn::Planes(p) => {
                let s = p.shape();
                (s[0], s[1], s[2])
            }
        }
    }
}

/// A [`Spikes`] or unpacked planes.
pub fn spikes_in<'py>(obj: &Bound<'py, PyAny>) -> PyResult<SpikesIn<'py>> {
    if let Ok(s) = obj.cast::<Spikes>() {
        let s = s.get();
        let py = obj.py();
        return Ok(SpikesIn::Packed {
            bits: s.bits(py),
            n: s.planes(py),
            height: s.height,
            width: s.width,
        });
    }
    Ok(SpikesIn::Planes(planes_in(obj)?))
}

/// Events as four columns with their sensor: ``t_ns`` (``int64``, non-decreasing), ``x`` and
/// ``y`` (``uint16``, row 0 at the top), ``polarity`` (``int8``, +1 ON, -1 OFF), covering
/// ``[t_start_ns, t_end_ns)``.
#[pyclass(module = "neuspike", frozen)]
pub struct Events {
    /// Sensor width in pixels.
    #[pyo3(get)]
    width: usize,
    /// Sensor height in pixels.
    #[pyo3(get)]
    height: usize,
    /// Start of the interval covered (inclusive), ns.
    #[pyo3(get)]
    t_start_ns: i64,
    /// End of the interval covered (exclusive), ns.
    #[pyo3(get)]
    t_end_ns: i64,
    t_ns: Py<PyArray1<i64>>,
    x: Py<PyArray1<u16>>,
    y: Py<PyArray1<u16>>,
    polarity: Py<PyArray1<i8>>,
}

/// Borrowed columns of an [`Events`], for a kernel.
pub struct Columns<'py> {
    t_ns: numpy::PyReadonlyArray1<'py, i64>,
    x: numpy::PyReadonlyArray1<'py, u16>,
    y: numpy::PyReadonlyArray1<'py, u16>,
    polarity: numpy::PyReadonlyArray1<'py, i8>,
}

impl Columns<'_> {
    /// The columns as the kernels take them.
    pub fn slice(&self) -> PyResult<EventSlice<'_>> {
        Ok(EventSlice {
            t_ns: self.t_ns.as_slice().map_err(errors::input)?,
            x: self.x.as_slice().map_err(errors::input)?,
            y: self.y.as_slice().map_err(errors::input)?,
            polarity: self.polarity.as_slice().map_err(errors::input)?,
        })
    }
}

impl Events {
    /// A batch's columns, handed to numpy without a copy.
    pub fn from_batch(py: Python<'_>, b: EventBatch) -> Events {
        Events {
            width: b.width,
            height: b.height,
            t_start_ns: b.t_start_ns,
            t_end_ns: b.t_end_ns,
            t_ns: PyArray1::from_vec(py, b.t_ns).unbind(),
            x: PyArray1::from_vec(py, b.x).unbind(),
            y: PyArray1::from_vec(py, b.y).unbind(),
            polarity: PyArray1::from_vec(py, b.polarity).unbind(),
        }
    }

    pub fn columns<'py>(&self, py: Python<'py>) -> Columns<'py> {
        Columns {
            t_ns: self.t_ns.bind(py).readonly(),
            x: self.x.bind(py).readonly(),
            y: self.y.bind(py).readonly(),
            polarity: self.polarity.bind(py).readonly(),
        }
    }

    pub fn sensor(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    pub fn len(&self, py: Python<'_>) -> usize {
        self.t_ns.bind(py).len()
    }

    pub fn interval(&self) -> (i64, i64) {
        (self.t_start_ns, self.t_end_ns)
    }
}

/// A column as `dtype`: the array itself where it is one, else converted, and refused where the
/// conversion would change a value (a negative column, a fractional time), naming the first.
fn column<'py, T: numpy::Element>(
    py: Python<'py>,
    obj: &Bound<'py, PyAny>,
    dtype: &str,
    name: &str,
) -> PyResult<Bound<'py, PyArray1<T>>> {
    let np = py.import("numpy")?;
    let original = np.call_method1("asarray", (obj,))?;
    let kwargs = pyo3::types::PyDict::new(py);
    kwargs.set_item("copy", false)?;
    let cast = original.call_method("astype", (dtype,), Some(&kwargs))?;
    let converted = contiguous(py, &cast, dtype)?;
    if original.getattr("dtype")?.str()? != dtype {
        let same = converted.call_method1("__eq__", (&original,))?;
        if !np.call_method1("all", (&same,))?.is_truthy()? {
            let i: usize = np
                .call_method1("argmin", (&same,))?
                .extract()
                .unwrap_or_default();
            let v = original.get_item(i)?;
            return Err(errors::input(format!(
                "{name}: value {v} at index {i} is not a {dtype}"
            )));
        }
    }
    converted
        .cast_into::<PyArray1<T>>()
        .map_err(|_| errors::input(format!("{name}: expected a 1-D array of {dtype}")))
}

#[pymethods]
impl Events {
    /// Events from four columns (converted to ``int64``, ``uint16``, ``uint16``, ``int8`` where
    /// they are not, read in place where they are). The interval defaults to the first event's
    /// time and one past the last (``[0, 0)`` without events).
    #[new]
    #[pyo3(signature = (t_ns, x, y, polarity, width, height, *, t_start_ns = None, t_end_ns = None))]
    fn new(
        py: Python<'_>,
        t_ns: &Bound<'_, PyAny>,
        x: &Bound<'_, PyAny>,
        y: &Bound<'_, PyAny>,
        polarity: &Bound<'_, PyAny>,
        width: usize,
        height: usize,
        t_start_ns: Option<i64>,
        t_end_ns: Option<i64>,
    ) -> PyResult<Events> {
        if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
            return Err(errors::input(format!(
                "events: a sensor of {width}x{height}: each side must be 1..={MAX_SIDE}"
            )));
        }
        let t_ns = column::<i64>(py, t_ns, "int64", "t_ns")?;
        let x = column::<u16>(py, x, "uint16", "x")?;
        let y = column::<u16>(py, y, "uint16", "y")?;
        let polarity = column::<i8>(py, polarity, "int8", "polarity")?;
        let n = t_ns.len();
        for (name, len) in [("x", x.len()), ("y", y.len()), ("polarity", polarity.len())] {
            if len != n {
                return Err(errors::input(format!(
                    "events: {name} has {len} values, t_ns has {n}"
                )));
            }
        }
        let (first, last) = {
            let t = t_ns.readonly();
            let t = t.as_slice().map_err(errors::input)?;
            (t.first().copied(), t.last().copied())
        };
        Ok(Events {
            width,
            height,
            t_start_ns: t_start_ns.or(first).unwrap_or(0),
            t_end_ns: t_end_ns.or(last.map(|t| t.saturating_add(1))).unwrap_or(0),
            t_ns: t_ns.unbind(),
            x: x.unbind(),
            y: y.unbind(),
            polarity: polarity.unbind(),
        })
    }

    /// Events from a structured array with fields ``t_ns``, ``x``, ``y``, ``polarity``.
    #[staticmethod]
    #[pyo3(signature = (array, width, height, *, t_start_ns = None, t_end_ns = None))]
    fn from_structured(
        py: Python<'_>,
        array: &Bound<'_, PyAny>,
        width: usize,
        height: usize,
        t_start_ns: Option<i64>,
        t_end_ns: Option<i64>,
    ) -> PyResult<Events> {
        let field = |name: &str| {
            array.get_item(name).map_err(|_| {
                errors::input(format!(
                    "events: the structured array has no field {name:?} (it needs t_ns, x, y, polarity)"
                ))
            })
        };
        Events::new(
            py,
            &field("t_ns")?,
            &field("x")?,
            &field("y")?,
            &field("polarity")?,
            width,
            height,
            t_start_ns,
            t_end_ns,
        )
    }

    /// The events as one structured array (a copy): fields ``t_ns`` ``<i8``, ``x`` ``<u2``,
    /// ``y`` ``<u2``, ``polarity`` ``i1``.
    fn to_structured<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let np = py.import("numpy")?;
        let dtype = np.call_method1(
            "dtype",
            (vec![
                ("t_ns", "<i8"),
                ("x", "<u2"),
                ("y", "<u2"),
                ("polarity", "i1"),
            ],),
        )?;
        let out = np.call_method1("empty", (self.len(py), dtype))?;
        out.set_item("t_ns", self.t_ns.bind(py))?;
        out.set_item("x", self.x.bind(py))?;
        out.set_item("y", self.y.bind(py))?;
        out.set_item("polarity", self.polarity.bind(py))?;
        Ok(out)
    }

    /// Timestamps, ``int64`` ns (the array itself).
    #[getter]
    fn t_ns<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        self.t_ns.bind(py).clone()
    }

    /// Columns, ``uint16``.
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u16>> {
        self.x.bind(py).clone()
    }

    /// Rows, ``uint16`` (row 0 at the top).
    #[getter]
    fn y<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u16>> {
        self.y.bind(py).clone()
    }

    /// ``int8``: +1 ON (brighter), -1 OFF (darker).
    #[getter]
    fn polarity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i8>> {
        self.polarity.bind(py).clone()
    }

    fn __len__(&self, py: Python<'_>) -> usize {
        self.len(py)
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Events({} events on {}x{}, [{}, {}) ns)",
            self.len(py),
            self.width,
            self.height,
            self.t_start_ns,
            self.t_end_ns
        )
    }
}
