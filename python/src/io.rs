//! Every reader and writer of `neuspike-formats`, on [`Spikes`] and [`Events`]; streaming
//! iterators for files larger than memory.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use ndarray::Array3;
use numpy::PyArray1;
use pyo3::prelude::*;

use neuspike_formats::aedat4::{Aedat4Frames, Aedat4Writer, Compression};
use neuspike_formats::dat::DatWriter;
use neuspike_formats::pku::{self, PkuGeometry, PkuOptions, PkuReader, PkuWriter};
use neuspike_formats::raw::{Evt2Writer, Evt3Writer};
use neuspike_formats::text::TextWriter;
use neuspike_formats::{
    Event, EventWriter, FormatError, ReadOptions, Resolution, WriteSummary, open_events,
};

use crate::values::{Events, Spikes, SpikesIn, spikes_in};
use crate::{errors, threads};

/// Events a reader hands out at once unless told otherwise.
const DEFAULT_CHUNK_EVENTS: usize = 1 << 20;
/// Planes a spike reader hands out at once unless told otherwise.
const DEFAULT_CHUNK_PLANES: usize = 1000;

fn pku_options(
    width: usize,
    height: usize,
    head_columns: usize,
    plane_period_ns: i64,
    t_first_ns: i64,
) -> PyResult<PkuOptions> {
    let sides = 1..=crate::values::MAX_SIDE;
    if !sides.contains(&width) || !sides.contains(&height) {
        return Err(errors::config(format!(
            "width x height = {width}x{height}: each side must be 1..={}",
            crate::values::MAX_SIDE
        )));
    }
    if head_columns != 0 && head_columns != pku::HEAD_COLUMNS {
        return Err(errors::config(format!(
            "head_columns = {head_columns}: must be 0 or {}",
            pku::HEAD_COLUMNS
        )));
    }
    if plane_period_ns <= 0 {
        return Err(errors::config(format!(
            "plane_period_ns = {plane_period_ns}: must be > 0"
        )));
    }
    Ok(PkuOptions {
        geometry: PkuGeometry {
            width,
            height,
            head_columns,
        },
        plane_period_ns,
        t_first_ns,
    })
}

/// Reads a PKU spike ``.dat`` file (rows stored bottom-up, turned top-down) into one
/// :class:`Spikes`: every plane, or the first ``max_planes``. Use :class:`SpikeReader` for files
/// larger than memory, and to keep the planes before a damaged tail.
#[pyfunction]
#[pyo3(signature = (path, *, width = 400, height = 250, head_columns = 0, plane_period_ns = 50_000, t_first_ns = 0, max_planes = None))]
pub fn read_spikes(
    py: Python<'_>,
    path: PathBuf,
    width: usize,
    height: usize,
    head_columns: usize,
    plane_period_ns: i64,
    t_first_ns: i64,
    max_planes: Option<u64>,
) -> PyResult<Spikes> {
    let opts = pku_options(width, height, head_columns, plane_period_ns, t_first_ns)?;
    let chunk = threads::run(py, || -> Result<_, FormatError> {
        let count = pku::plane_count(&path, &opts.geometry)?;
        let n = max_planes.map_or(count, |m| m.min(count));
        let mut reader = PkuReader::open(&path, &opts)?;
        reader.next_chunk(usize::try_from(n).unwrap_or(usize::MAX))
    })?
    .map_err(errors::format)?;
    match chunk {
        Some(c) => Spikes::from_chunk(py, c),
        None => Spikes::from_bits(
            py,
            Vec::new(),
            0,
            opts.geometry.plane_bytes(),
            crate::values::Clock {
                width,
                height,
                first_plane: 0,
                t_first_ns,
                plane_period_ns,
                lum_per_rate: None,
            },
        ),
    }
}

/// A PKU spike ``.dat`` file read as it is iterated: :class:`Spikes` of ``chunk_planes`` planes
/// each (the last one shorter), with bounded memory whatever the file's size. A damaged tail
/// raises :class:`FormatError` after every whole plane before it was handed out.
#[pyclass(module = "neuspike", frozen)]
pub struct SpikeReader {
    reader: Mutex<PkuReader<File>>,
    chunk_planes: usize,
}

#[pymethods]
impl SpikeReader {
    #[new]
    #[pyo3(signature = (path, *, chunk_planes = DEFAULT_CHUNK_PLANES, width = 400, height = 250, head_columns = 0, plane_period_ns = 50_000, t_first_ns = 0))]
    fn new(
        path: PathBuf,
        chunk_planes: usize,
        width: usize,
        height: usize,
        head_columns: usize,
        plane_period_ns: i64,
        t_first_ns: i64,
    ) -> PyResult<SpikeReader> {
        if chunk_planes == 0 {
            return Err(errors::config("chunk_planes = 0: must be at least 1"));
        }
        let opts = pku_options(width, height, head_columns, plane_period_ns, t_first_ns)?;
        let reader = PkuReader::open(&path, &opts).map_err(errors::format)?;
        Ok(SpikeReader {
            reader: Mutex::new(reader),
            chunk_planes,
        })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<Spikes>> {
        let mut reader = self.reader.lock().unwrap_or_else(|p| p.into_inner());
        let reader = &mut *reader;
        let n = self.chunk_planes;
        match threads::run(py, || reader.next_chunk(n))?.map_err(errors::format)? {
            Some(chunk) => Spikes::from_chunk(py, chunk).map(Some),
            None => Ok(None),
        }
    }

    /// Planes handed out so far.
    #[getter]
    fn planes_read(&self) -> u64 {
        self.reader
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .planes_read()
    }
}

/// Writes spike planes (a :class:`Spikes` or unpacked ``[N, H, W]``) as a PKU ``.dat`` file,
/// rows bottom-up as the camera stores them; returns the planes written.
#[pyfunction]
#[pyo3(signature = (path, spikes, *, head_columns = 0))]
pub fn write_spikes(
    py: Python<'_>,
    path: PathBuf,
    spikes: &Bound<'_, PyAny>,
    head_columns: usize,
) -> PyResult<u64> {
    let input = spikes_in(spikes)?;
    let (_, height, width) = input.dim();
    let opts = pku_options(width, height, head_columns, 1, 0)?;
    let packed;
    let bits: &[u8] = match &input {
        SpikesIn::Packed { bits, .. } => bits.as_slice().map_err(errors::input)?,
        SpikesIn::Planes(p) => {
            let view = crate::values::view3(p)?;
            packed = threads::run(py, || neuspike_schemas::pack_planes(view))?;
            &packed
        }
    };
    let summary = threads::run(py, || -> Result<WriteSummary, FormatError> {
        let file = create(&path)?;
        let mut w = PkuWriter::new(BufWriter::new(file), &path, opts.geometry)?;
        w.write_planes(bits)?;
        let (w, summary) = w.finish()?;
        flush(w, &path)?;
        Ok(summary)
    })?
    .map_err(errors::format)?;
    Ok(summary.items)
}

fn create(path: &Path) -> Result<File, FormatError> {
    File::create(path).map_err(|source| FormatError::Open {
        path: path.to_path_buf(),
        source,
    })
}

fn flush(w: BufWriter<File>, path: &Path) -> Result<(), FormatError> {
    w.into_inner()
        .map_err(|e| e.into_error())
        .and_then(|f| f.sync_all().map(|()| f))
        .map(drop)
        .map_err(|source| FormatError::Io {
            path: path.to_path_buf(),
            offset: 0,
            source,
        })
}

fn read_options(width: Option<u16>, height: Option<u16>) -> PyResult<ReadOptions> {
    match (width, height) {
        (Some(w), Some(h)) => Ok(ReadOptions::with_resolution(w, h)),
        (None, None) => Ok(ReadOptions::default()),
        _ => Err(errors::config(
            "width and height: give both (for a file that does not state its sensor) or neither",
        )),
    }
}

/// Reads an event file of any format neuspike reads (Event Camera Dataset text, Prophesee RAW
/// EVT 2.0/3.0 and DAT, AEDAT 4; told apart by content) into one :class:`Events`: every event,
/// or the first ``max_events``. ``width`` and ``height`` give the sensor of a file that does not
/// state it. Use :class:`EventReader` for files larger than memory.
#[pyfunction]
#[pyo3(signature = (path, *, width = None, height = None, max_events = None))]
pub fn read_events(
    py: Python<'_>,
    path: PathBuf,
    width: Option<u16>,
    height: Option<u16>,
    max_events: Option<usize>,
) -> PyResult<Events> {
    let opts = read_options(width, height)?;
    let batch = threads::run(py, || -> Result<_, FormatError> {
        let mut reader = open_events(&path, &opts)?;
        let r = reader.resolution();
        let mut batch =
            neuspike_schemas::EventBatch::empty(r.width.into(), r.height.into(), 0, 0, 0);
        let mut left = max_events.unwrap_or(usize::MAX);
        while left > 0 {
            let got = reader.read_into(&mut batch, left.min(DEFAULT_CHUNK_EVENTS))?;
            if got == 0 {
                break;
            }
            left -= got;
        }
        if let (Some(&first), Some(&last)) = (batch.t_ns.first(), batch.t_ns.last()) {
            batch.t_start_ns = first;
            batch.t_end_ns = last.saturating_add(1);
        }
        Ok(batch)
    })?
    .map_err(errors::format)?;
    Ok(Events::from_batch(py, batch))
}

/// An event file read as it is iterated: :class:`Events` of up to ``chunk_events`` events each,
/// with bounded memory. A damaged part raises :class:`FormatError` after every event before it
/// was handed out.
#[pyclass(module = "neuspike", frozen)]
pub struct EventReader {
    reader: Mutex<Box<dyn neuspike_formats::EventReader + Send>>,
    chunk_events: usize,
}

#[pymethods]
impl EventReader {
    #[new]
    #[pyo3(signature = (path, *, chunk_events = DEFAULT_CHUNK_EVENTS, width = None, height = None))]
    fn new(
        path: PathBuf,
        chunk_events: usize,
        width: Option<u16>,
        height: Option<u16>,
    ) -> PyResult<EventReader> {
        if chunk_events == 0 {
            return Err(errors::config("chunk_events = 0: must be at least 1"));
        }
        let opts = read_options(width, height)?;
        let reader = open_events(&path, &opts).map_err(errors::format)?;
        Ok(EventReader {
            reader: Mutex::new(reader),
            chunk_events,
        })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<Events>> {
        let mut reader = self.reader.lock().unwrap_or_else(|p| p.into_inner());
        let reader = &mut *reader;
        let n = self.chunk_events;
        match threads::run(py, || reader.next_chunk(n))?.map_err(errors::format)? {
            Some(batch) => Ok(Some(Events::from_batch(py, batch))),
            None => Ok(None),
        }
    }

    /// The sensor ``(width, height)`` every event is checked against.
    #[getter]
    fn resolution(&self) -> (u16, u16) {
        let r = self
            .reader
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .resolution();
        (r.width, r.height)
    }
}

/// The event formats neuspike writes, by name or by a file's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum EventFormat {
    #[cfg(feature = "hdf5")]
    Hdf5,
    Text,
    Evt2,
    Evt3,
    Dat,
    Aedat4,
}

impl EventFormat {
    #[cfg(not(feature = "hdf5"))]
    const NAMES: &str = "text (.txt), evt3 (.raw), evt2, dat (.dat), aedat4 (.aedat4); hdf5 in a build with the hdf5 feature";
    #[cfg(feature = "hdf5")]
    const NAMES: &str = "text (.txt), evt3 (.raw), evt2, dat (.dat), aedat4 (.aedat4), hdf5 (.h5)";

    fn named(name: &str) -> Option<Self> {
        Some(match name {
            #[cfg(feature = "hdf5")]
            "hdf5" | "h5" => EventFormat::Hdf5,
            "text" | "txt" => EventFormat::Text,
            "evt2" => EventFormat::Evt2,
            "evt3" | "raw" => EventFormat::Evt3,
            "dat" => EventFormat::Dat,
            "aedat4" => EventFormat::Aedat4,
            _ => return None,
        })
    }
}

fn write_with<W: EventWriter>(
    mut w: W,
    events: neuspike_representations::EventSlice<'_>,
) -> Result<W, FormatError> {
    for i in 0..events.len() {
        w.write_event(&Event {
            t_ns: events.t_ns[i],
            x: events.x[i],
            y: events.y[i],
            polarity: events.polarity[i],
        })?;
    }
    Ok(w)
}

/// Writes :class:`Events` to ``path`` in ``format`` (by default the one its extension names:
/// ``.txt`` Event Camera Dataset text, ``.raw`` Prophesee EVT 3.0, ``.dat`` Prophesee DAT,
/// ``.aedat4`` AEDAT 4 with LZ4, ``.h5`` HDF5 in a build with the ``hdf5`` feature; ``"evt2"``
/// for EVT 2.0); returns the events written. Formats that keep microseconds floor the
/// nanoseconds. An AEDAT 4 file also takes APS frames: ``aps=(t_ns, frames)``, luminance
/// ``[K, H, W]`` in ``[0, 1]`` of the sensor's size, stored as 16-bit grey.
#[pyfunction]
#[pyo3(signature = (path, events, *, format = None, aps = None))]
pub fn write_events(
    py: Python<'_>,
    path: PathBuf,
    events: &Bound<'_, Events>,
    format: Option<&str>,
    aps: Option<(Vec<i64>, Bound<'_, PyAny>)>,
) -> PyResult<u64> {
    let name = match format {
        Some(f) => f.to_owned(),
        None => path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase(),
    };
    let fmt = EventFormat::named(&name).ok_or_else(|| {
        errors::config(format!(
            "{}: format {name:?}: not one neuspike writes ({})",
            path.display(),
            EventFormat::NAMES
        ))
    })?;
    if aps.is_some() && fmt != EventFormat::Aedat4 {
        return Err(errors::config(format!(
            "{}: aps frames go in AEDAT 4 files only",
            path.display()
        )));
    }
    let ev = events.get();
    let (height, width) = ev.sensor();
    let frames = match aps {
        Some((t, frames)) => Some(aps_frames(py, t, &frames, (height, width))?),
        None => None,
    };
    let side = |v: usize, what: &str| {
        u16::try_from(v).map_err(|_| errors::config(format!("events {what} = {v}: above 65535")))
    };
    let res = Resolution::new(side(width, "width")?, side(height, "height")?);
    let columns = ev.columns(py);
    let slice = columns.slice()?;
    let summary = threads::run(py, || -> Result<WriteSummary, FormatError> {
        #[cfg(feature = "hdf5")]
        if fmt == EventFormat::Hdf5 {
            let w = neuspike_formats::hdf5::Hdf5Writer::create(&path, res)?;
            return write_with(w, slice)?.finish();
        }
        let w = BufWriter::new(create(&path)?);
        let (w, summary) = match fmt {
            #[cfg(feature = "hdf5")]
            EventFormat::Hdf5 => {
                return Err(FormatError::Unsupported {
                    path: path.clone(),
                    what: "HDF5 through a buffered file".into(),
                });
            }
            EventFormat::Text => {
                write_with(TextWriter::new(w, &path, res, true)?, slice)?.finish()?
            }
            EventFormat::Evt2 => write_with(Evt2Writer::new(w, &path, res)?, slice)?.finish()?,
            EventFormat::Evt3 => write_with(Evt3Writer::new(w, &path, res)?, slice)?.finish()?,
            EventFormat::Dat => write_with(DatWriter::new(w, &path, res)?, slice)?.finish()?,
            EventFormat::Aedat4 => {
                let mut w = Aedat4Writer::new(w, &path, res, Compression::Lz4)?;
                let frames = frames.unwrap_or_default();
                // Frames and events interleaved by time: a frame before the events after it.
                let mut next = frames.iter().peekable();
                for i in 0..slice.len() {
                    while let Some(f) = next.next_if(|f| f.t_ns <= slice.t_ns[i]) {
                        w.write_frame(f)?;
                    }
                    w.write_event(&Event {
                        t_ns: slice.t_ns[i],
                        x: slice.x[i],
                        y: slice.y[i],
                        polarity: slice.polarity[i],
                    })?;
                }
                for f in next {
                    w.write_frame(f)?;
                }
                w.finish()?
            }
        };
        flush(w, &path)?;
        Ok(summary)
    })?
    .map_err(errors::format)?;
    Ok(summary.items)
}

/// APS frames from Python: times and luminance ``[K, H, W]`` in ``[0, 1]``, as 16-bit grey frames
/// of the sensor's size.
fn aps_frames(
    py: Python<'_>,
    t_ns: Vec<i64>,
    frames: &Bound<'_, PyAny>,
    sensor: (usize, usize),
) -> PyResult<Vec<neuspike_formats::aedat4::ApsFrame>> {
    let frames = crate::values::contiguous(py, frames, "float32")?
        .extract::<numpy::PyReadonlyArray3<'_, f32>>()
        .map_err(|_| errors::input("aps: expected (t_ns [K], frames [K, H, W])"))?;
    let view = crate::values::view3(&frames)?;
    let (k, h, w) = view.dim();
    if (h, w) != sensor || k != t_ns.len() {
        return Err(errors::input(format!(
            "aps: {} times and frames [{k}, {h}, {w}] for a {}x{} sensor: one time a frame, the sensor's size",
            t_ns.len(),
            sensor.1,
            sensor.0
        )));
    }
    if t_ns.windows(2).any(|p| p[1] < p[0]) {
        return Err(errors::input("aps: the frames' times must not decrease"));
    }
    let side = |v: usize| {
        u16::try_from(v).map_err(|_| errors::input(format!("aps: a side of {v} pixels")))
    };
    let (wu, hu) = (side(w)?, side(h)?);
    Ok(view
        .outer_iter()
        .zip(t_ns)
        .map(|(f, t)| neuspike_formats::aedat4::ApsFrame {
            t_ns: t,
            exposure_begin_ns: t,
            exposure_end_ns: t,
            format: neuspike_formats::aedat4::FrameFormat::Gray16,
            width: wu,
            height: hu,
            pixels: f
                .iter()
                .flat_map(|&v| ((v.clamp(0.0, 1.0) * 65_535.0).round() as u16).to_le_bytes())
                .collect(),
        })
        .collect())
}

/// The APS frames of an AEDAT 4 file (its first frame stream): ``(t_ns, frames)``, ``int64 [K]``
/// and ``float32 [K, H, W]`` luminance in ``[0, 1]`` (grey / 255 or / 65535, colour by the BT.601
/// weights). Frames of another size than the first raise :class:`FormatError`.
#[pyfunction]
pub fn read_aps_frames<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Bound<'py, PyArray1<i64>>, Bound<'py, PyAny>)> {
    let (times, frames) = threads::run(py, || -> Result<_, FormatError> {
        let mut times = Vec::new();
        let mut pixels = Vec::new();
        let mut size = None;
        for frame in Aedat4Frames::open(&path)? {
            let frame = frame?;
            let (w, h) = (usize::from(frame.width), usize::from(frame.height));
            match size {
                None => size = Some((h, w)),
                Some(s) if s == (h, w) => {}
                Some((h0, w0)) => {
                    return Err(FormatError::Unsupported {
                        path: path.clone(),
                        what: format!(
                            "APS frame {} is {w}x{h}, the first was {w0}x{h0}",
                            times.len()
                        ),
                    });
                }
            }
            times.push(frame.t_ns);
            pixels.extend(frame.luminance());
        }
        let (h, w) = size.unwrap_or((0, 0));
        let frames = Array3::from_shape_vec((times.len(), h, w), pixels).map_err(|e| {
            FormatError::Unsupported {
                path: path.clone(),
                what: e.to_string(),
            }
        })?;
        Ok((times, frames))
    })?
    .map_err(errors::format)?;
    Ok((
        PyArray1::from_vec(py, times),
        crate::values::to_numpy(py, frames)?,
    ))
}

/// The APS frames of an AEDAT 4 file read as it is iterated, one ``(t_ns, frame)`` at a time
/// (``frame`` ``float32 [H, W]`` luminance in ``[0, 1]``), with bounded memory; a damaged packet
/// raises :class:`FormatError` after every frame before it.
#[pyclass(module = "neuspike", frozen)]
pub struct ApsFrameReader {
    frames: Mutex<Aedat4Frames<std::io::BufReader<File>>>,
}

#[pymethods]
impl ApsFrameReader {
    #[new]
    fn new(path: PathBuf) -> PyResult<ApsFrameReader> {
        let frames = Aedat4Frames::open(&path).map_err(errors::format)?;
        Ok(ApsFrameReader {
            frames: Mutex::new(frames),
        })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Option<(i64, Bound<'py, PyAny>)>> {
        let mut frames = self.frames.lock().unwrap_or_else(|p| p.into_inner());
        let frames = &mut *frames;
        let next = threads::run(py, || {
            frames.next().map(|f| {
                f.map(|f| {
                    let (h, w) = (usize::from(f.height), usize::from(f.width));
                    (
                        f.t_ns,
                        ndarray::Array2::from_shape_vec((h, w), f.luminance()),
                    )
                })
            })
        })?;
        match next {
            None => Ok(None),
            Some(Err(e)) => Err(errors::format(e)),
            Some(Ok((t_ns, pixels))) => {
                let pixels = pixels.map_err(errors::input)?;
                Ok(Some((t_ns, crate::values::to_numpy(py, pixels)?)))
            }
        }
    }
}

/// A summary of any recording neuspike reads, told apart by content: a dict with ``kind``
/// (``"spikes"`` or ``"events"``), ``format``, the counts and times, and ``text`` (what
/// ``neuspike info`` prints). Spike files are read as ``width`` x ``height`` planes; an event
/// file that does not state its sensor is read without bounds.
#[pyfunction]
#[pyo3(signature = (path, *, width = 400, height = 250, head_columns = 0, plane_period_ns = 50_000))]
pub fn info<'py>(
    py: Python<'py>,
    path: PathBuf,
    width: usize,
    height: usize,
    head_columns: usize,
    plane_period_ns: i64,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let spikes = pku_options(width, height, head_columns, plane_period_ns, 0)?;
    let events = ReadOptions {
        allow_unknown_size: true,
        ..ReadOptions::default()
    };
    let i = threads::run(py, || neuspike_formats::info(&path, &spikes, &events))?
        .map_err(errors::format)?;
    let d = pyo3::types::PyDict::new(py);
    d.set_item("text", i.to_string())?;
    match i {
        neuspike_formats::Info::Spikes(s) => {
            d.set_item("kind", "spikes")?;
            d.set_item("format", "PKU spike planes")?;
            d.set_item("planes", s.planes)?;
            d.set_item("spikes", s.spikes)?;
            d.set_item("width", s.geometry.width)?;
            d.set_item("height", s.geometry.height)?;
            d.set_item("bytes", s.bytes)?;
            d.set_item("plane_period_ns", s.plane_period_ns)?;
            d.set_item("duration_ns", s.duration_ns())?;
            d.set_item("firing_probability", s.firing_probability())?;
            d.set_item("partial_tail_bytes", s.partial_tail.map(|(_, b)| b))?;
        }
        neuspike_formats::Info::Events(e) => {
            d.set_item("kind", "events")?;
            d.set_item("format", e.format.to_string())?;
            d.set_item("events", e.stats.events)?;
            d.set_item("on_events", e.stats.on_events)?;
            d.set_item("width", e.resolution.map(|r| r.width))?;
            d.set_item("height", e.resolution.map(|r| r.height))?;
            d.set_item("first_t_ns", e.stats.first_t_ns)?;
            d.set_item("last_t_ns", e.stats.last_t_ns)?;
            d.set_item("duration_ns", e.stats.duration_ns())?;
            d.set_item("aps_frames", e.aps.map(|a| a.frames))?;
        }
    }
    Ok(d)
}

/// Ground truth recorded with a spike file, as ``neuspike simulate`` writes it: a folder whose
/// ``timestamps.txt`` lists ``plane t_ns file`` and the PNGs it names. Returns ``(planes,
/// frames)``: ``uint64 [K]`` and luminance ``float32 [K, H, W]`` in ``[0, 1]``.
#[pyfunction]
pub fn read_truth<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let list = neuspike_formats::truth::TruthList::open(&path).map_err(errors::format_text)?;
    let (planes, frames) = threads::run(py, || -> Result<_, String> {
        let mut planes = Vec::with_capacity(list.frames.len());
        let mut frames = Vec::with_capacity(list.frames.len());
        for (plane, png) in &list.frames {
            let f = neuspike_image::read_frame_png(png)
                .map_err(|e| format!("{}: {e}", png.display()))?;
            if let Some(first) = frames.first().map(|a: &ndarray::Array2<f32>| a.dim())
                && first != f.dim()
            {
                return Err(format!(
                    "{}: {}x{}, the first frame is {}x{}",
                    png.display(),
                    f.ncols(),
                    f.nrows(),
                    first.1,
                    first.0
                ));
            }
            planes.push(*plane);
            frames.push(f);
        }
        Ok((planes, frames))
    })?
    .map_err(errors::format_text)?;
    let views: Vec<_> = frames.iter().map(|f| f.view()).collect();
    let stacked = crate::values::stack_on_pool(py, &views)?;
    Ok((
        crate::values::to_numpy(py, ndarray::Array1::from(planes))?,
        crate::values::to_numpy(py, stacked)?,
    ))
}
