//! HDF5 event files: one-dimensional datasets `t`, `x`, `y` and `p` of equal length, at the root
//! or in a group `events` (the layout of PKU-Vidar-DVS, DSEC and similar sets). Built only with
//! the `hdf5` feature: it links the system's libhdf5 (Debian: `apt install libhdf5-dev`).
//!
//! Conventions, and what the reader accepts:
//! - `t`: integers in the unit its `unit` attribute names (`ns`, `us`, `ms` or `s`), microseconds
//!   when it has none (the convention of the sets above); or floats in seconds (unless `unit`
//!   says otherwise), rounded to the nearest ns. A scalar `t_offset` beside the datasets (DSEC),
//!   in the same unit, is added. Times must be non-decreasing (see [`ReadOptions::disorder`]).
//! - `x`, `y`: integers inside the sensor. `p`: 0 / 1 or -1 / +1 (OFF / ON); any other value is
//!   an error naming the event.
//! - The sensor size: `width` and `height` attributes of the group, else
//!   [`ReadOptions::resolution`].
//! - Integer datasets are read through libhdf5's conversion to `i64` (exact for every integer
//!   type up to `i64`), a block of [`BLOCK`] events at a time: memory stays bounded whatever the
//!   file size. Filters the library has (deflate, shuffle) work; others (Prophesee's ECF codec,
//!   Blosc) are reported by the library as an error naming the dataset.
//!
//! [`Hdf5Writer`] writes `events/{t,x,y,p}` (`t` in µs, `unit = "us"`, `x`, `y` as `u16`, `p` as
//! `u8` 0/1) in chunked, resizable, deflated datasets, with `width` and `height` on the group.

use std::path::{Path, PathBuf};

use hdf5_metno as h5;
/// The HDF5 library binding, for callers (and tests) that make their own files.
pub use hdf5_metno as lib;
use hdf5_metno::types::{TypeDescriptor, VarLenUnicode};
use neuspike_schemas::{Event, EventBatch};

use crate::binary::WriteSummary;
use crate::error::{FormatError, Location, Result};
use crate::events::{Bounds, EventReader, ReadOptions, Resolution, Sink};
use crate::header::resolve_resolution;

/// Events read per dataset access.
pub const BLOCK: usize = 1 << 16;

/// The unit of `t`.
#[derive(Clone, Copy, Debug, PartialEq)]
enum TimeUnit {
    /// Integers, so many ns each.
    Int(i64),
    /// Floats, so many ns each.
    Float(f64),
}

/// A streaming reader of an HDF5 event file.
pub struct Hdf5Reader {
    t: h5::Dataset,
    x: h5::Dataset,
    y: h5::Dataset,
    p: h5::Dataset,
    unit: TimeUnit,
    /// `t_offset`, in the unit of `t`.
    offset: i64,
    len: usize,
    next: usize,
    group: String,
    sink: Sink,
}

impl Hdf5Reader {
    /// Opens the file at `path`.
    pub fn open(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Self> {
        let path = path.as_ref();
        let allow_unknown_size = opts.allow_unknown_size;
        if !path.exists() {
            return Err(FormatError::Open {
                path: path.to_path_buf(),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            });
        }
        let lib = |what: &str, e: h5::Error| FormatError::Header {
            path: path.to_path_buf(),
            what: format!("{what}: {e}"),
        };
        let file = h5::File::open(path).map_err(|e| lib("libhdf5 cannot open it", e))?;
        let root = file.as_group().map_err(|e| lib("root group", e))?;
        let (group, name) = if root.link_exists("events") {
            (
                root.group("events").map_err(|e| lib("group `events`", e))?,
                "/events/".to_string(),
            )
        } else {
            (root, "/".to_string())
        };
        let members = group.member_names().unwrap_or_default();
        let dataset = |n: &str| -> Result<h5::Dataset> {
            if !members.iter().any(|m| m == n) {
                return Err(FormatError::Header {
                    path: path.to_path_buf(),
                    what: format!(
                        "no dataset `{name}{n}` (the group holds: {}); event files need t, x, y and p",
                        members.join(", ")
                    ),
                });
            }
            let d = group
                .dataset(n)
                .map_err(|e| lib(&format!("dataset `{name}{n}`"), e))?;
            if d.ndim() != 1 {
                return Err(FormatError::Header {
                    path: path.to_path_buf(),
                    what: format!(
                        "dataset `{name}{n}` has shape {:?}, not one dimension",
                        d.shape()
                    ),
                });
            }
            Ok(d)
        };
        let (t, x, y, p) = (dataset("t")?, dataset("x")?, dataset("y")?, dataset("p")?);
        let len = t.size();
        for (n, d) in [("x", &x), ("y", &y), ("p", &p)] {
            if d.size() != len {
                return Err(FormatError::Header {
                    path: path.to_path_buf(),
                    what: format!(
                        "dataset `{name}{n}` holds {} values, `{name}t` {len}",
                        d.size()
                    ),
                });
            }
        }
        let unit = time_unit(&t).map_err(|what| FormatError::Header {
            path: path.to_path_buf(),
            what: format!("`{name}t`: {what}"),
        })?;
        let offset = if members.iter().any(|m| m == "t_offset") {
            group
                .dataset("t_offset")
                .and_then(|d| d.read_scalar::<i64>())
                .map_err(|e| lib(&format!("`{name}t_offset`"), e))?
        } else {
            0
        };
        let size = |key: &str| -> Option<u16> {
            group
                .attr(key)
                .ok()?
                .read_scalar::<i64>()
                .ok()?
                .try_into()
                .ok()
        };
        let stated = match (size("width"), size("height")) {
            (Some(w), Some(h)) => Some(Resolution::new(w, h)),
            _ => None,
        };
        let resolution = resolve_resolution(
            stated,
            opts.resolution,
            path,
            allow_unknown_size,
            "the group has no `width` and `height` attributes",
        )?;
        Ok(Hdf5Reader {
            t,
            x,
            y,
            p,
            unit,
            offset,
            len,
            next: 0,
            group: name,
            sink: Sink::new(
                path.to_path_buf(),
                resolution.map_or(Bounds::Unknown, Bounds::Sensor),
                opts,
            ),
        })
    }

    /// The sensor size, when the file or the options give one.
    pub(crate) fn known_resolution(&self) -> Option<Resolution> {
        self.sink.known
    }

    /// Events in the file.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the file holds no event.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// The unit of `t`, from its type and `unit` attribute.
fn time_unit(t: &h5::Dataset) -> std::result::Result<TimeUnit, String> {
    let descriptor = t
        .dtype()
        .and_then(|d| d.to_descriptor())
        .map_err(|e| format!("unreadable type: {e}"))?;
    let float = match descriptor {
        TypeDescriptor::Integer(_) | TypeDescriptor::Unsigned(_) => false,
        TypeDescriptor::Float(_) => true,
        other => return Err(format!("type {other:?}, not integers or floats")),
    };
    let stated = t
        .attr("unit")
        .ok()
        .and_then(|a| a.read_scalar::<VarLenUnicode>().ok())
        .map(|s| s.as_str().trim().to_string());
    let ns = match stated.as_deref() {
        Some("ns") => 1,
        Some("us") | Some("µs") => 1_000,
        Some("ms") => 1_000_000,
        Some("s") => 1_000_000_000,
        Some(other) => return Err(format!("unit `{other}` (ns, us, ms or s are read)")),
        None if float => 1_000_000_000,
        None => 1_000,
    };
    Ok(if float {
        TimeUnit::Float(ns as f64)
    } else {
        TimeUnit::Int(ns)
    })
}

impl EventReader for Hdf5Reader {
    crate::events::sink_accessors!();

    fn read_into(&mut self, out: &mut EventBatch, max: usize) -> Result<usize> {
        let Hdf5Reader {
            t,
            x,
            y,
            p,
            unit,
            offset,
            len,
            next,
            group,
            sink,
        } = self;
        sink.read_with(out, max, |sink, out| {
            while !sink.full() {
                if *next == *len {
                    sink.finish();
                    return Ok(());
                }
                let n = (*len - *next).min(BLOCK).min(sink.room());
                let range = *next..*next + n;
                let lib = |d: &str, e: h5::Error| FormatError::Corrupt {
                    path: sink.path.clone(),
                    offset: range.start as u64,
                    what: format!("reading `{group}{d}` at event {}: {e}", range.start),
                };
                let ints = |ds: &h5::Dataset, d: &str| -> Result<Vec<i64>> {
                    Ok(ds
                        .read_slice_1d::<i64, _>(range.clone())
                        .map_err(|e| lib(d, e))?
                        .into_raw_vec_and_offset()
                        .0)
                };
                let ts: Vec<i64> = match *unit {
                    TimeUnit::Int(k) => ints(t, "t")?
                        .into_iter()
                        .map(|v| v.checked_add(*offset).and_then(|v| v.checked_mul(k)))
                        .collect::<Option<_>>()
                        .ok_or_else(|| bad(sink, group, &range, "t", "overflows i64 ns"))?,
                    TimeUnit::Float(k) => {
                        let fs = t
                            .read_slice_1d::<f64, _>(range.clone())
                            .map_err(|e| lib("t", e))?;
                        let mut ts = Vec::with_capacity(n);
                        for (i, &v) in fs.iter().enumerate() {
                            let ns = ((v + *offset as f64) * k).round();
                            if !ns.is_finite() || ns.abs() >= 9.2e18 {
                                return Err(bad(
                                    sink,
                                    group,
                                    &(range.start + i..range.end),
                                    "t",
                                    &format!("{v} is not a time"),
                                ));
                            }
                            ts.push(ns as i64);
                        }
                        ts
                    }
                };
                let (xs, ys, ps) = (ints(x, "x")?, ints(y, "y")?, ints(p, "p")?);
                for i in 0..n {
                    let at = Location::Byte((range.start + i) as u64);
                    let on = match ps[i] {
                        1 => true,
                        0 | -1 => false,
                        v => {
                            return Err(FormatError::Polarity {
                                path: sink.path.clone(),
                                at,
                                value: v,
                            });
                        }
                    };
                    let coord = |v: i64| u32::try_from(v).unwrap_or(u32::MAX);
                    sink.emit(out, ts[i], coord(xs[i]), coord(ys[i]), on, at)?;
                    *next += 1;
                }
            }
            Ok(())
        })
    }
}

#[cold]
fn bad(
    sink: &Sink,
    group: &str,
    range: &std::ops::Range<usize>,
    d: &str,
    what: &str,
) -> FormatError {
    FormatError::Corrupt {
        path: sink.path.clone(),
        offset: range.start as u64,
        what: format!("`{group}{d}` near event {}: {what}", range.start),
    }
}

/// Writes `events/{t,x,y,p}` (see the module's documentation).
pub struct Hdf5Writer {
    path: PathBuf,
    file: h5::File,
    t: h5::Dataset,
    x: h5::Dataset,
    y: h5::Dataset,
    p: h5::Dataset,
    resolution: Resolution,
    pending: EventBatch,
    written: usize,
    last_t_ns: Option<i64>,
    summary: WriteSummary,
}

impl Hdf5Writer {
    /// Creates (or truncates) the file at `path`.
    pub fn create(path: impl AsRef<Path>, resolution: Resolution) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let lib = |e: h5::Error| FormatError::Io {
            path: path.clone(),
            offset: 0,
            source: std::io::Error::other(e.to_string()),
        };
        let file = h5::File::create(&path).map_err(lib)?;
        let group = file.create_group("events").map_err(lib)?;
        for (key, v) in [("width", resolution.width), ("height", resolution.height)] {
            group
                .new_attr::<u16>()
                .create(key)
                .and_then(|a| a.write_scalar(&v))
                .map_err(lib)?;
        }
        let make = |name: &str, builder: h5::DatasetBuilderEmpty| {
            builder
                .shape(0..)
                .chunk(BLOCK)
                .deflate(1)
                .create(name)
                .map_err(lib)
        };
        let t = make("t", group.new_dataset::<i64>())?;
        let unit: VarLenUnicode = "us".parse().map_err(|_| lib(h5::Error::from("unit")))?;
        t.new_attr::<VarLenUnicode>()
            .create("unit")
            .and_then(|a| a.write_scalar(&unit))
            .map_err(lib)?;
        let x = make("x", group.new_dataset::<u16>())?;
        let y = make("y", group.new_dataset::<u16>())?;
        let p = make("p", group.new_dataset::<u8>())?;
        Ok(Hdf5Writer {
            path,
            file,
            t,
            x,
            y,
            p,
            resolution,
            pending: EventBatch::default(),
            written: 0,
            last_t_ns: None,
            summary: WriteSummary::default(),
        })
    }

    fn flush(&mut self) -> Result<()> {
        let n = self.pending.len();
        if n == 0 {
            return Ok(());
        }
        let lib = |e: h5::Error| FormatError::Io {
            path: self.path.clone(),
            offset: self.written as u64,
            source: std::io::Error::other(e.to_string()),
        };
        let (a, b) = (self.written, self.written + n);
        let t_us: Vec<i64> = self.pending.t_ns.iter().map(|t| t / 1000).collect();
        let p: Vec<u8> = self
            .pending
            .polarity
            .iter()
            .map(|&v| u8::from(v > 0))
            .collect();
        for d in [&self.t, &self.x, &self.y, &self.p] {
            d.resize(b).map_err(lib)?;
        }
        self.t.write_slice(&t_us, a..b).map_err(lib)?;
        self.x.write_slice(&self.pending.x, a..b).map_err(lib)?;
        self.y.write_slice(&self.pending.y, a..b).map_err(lib)?;
        self.p.write_slice(&p, a..b).map_err(lib)?;
        self.written = b;
        self.pending = EventBatch::default();
        Ok(())
    }

    /// Writes out what is pending and closes the file.
    pub fn finish(mut self) -> Result<WriteSummary> {
        self.flush()?;
        self.file.flush().map_err(|e| FormatError::Io {
            path: self.path.clone(),
            offset: self.written as u64,
            source: std::io::Error::other(e.to_string()),
        })?;
        Ok(self.summary)
    }
}

impl crate::EventWriter for Hdf5Writer {
    fn write_event(&mut self, e: &Event) -> Result<()> {
        let index = self.summary.items;
        let unwritable = |what: String| FormatError::Unwritable {
            path: self.path.clone(),
            index,
            what,
        };
        if e.x >= self.resolution.width || e.y >= self.resolution.height {
            return Err(unwritable(format!(
                "({}, {}) is outside the {} sensor",
                e.x, e.y, self.resolution
            )));
        }
        if e.t_ns < 0 || self.last_t_ns.is_some_and(|l| e.t_ns < l) {
            return Err(unwritable(format!(
                "timestamp {} ns is negative or before the previous one",
                e.t_ns
            )));
        }
        if e.polarity != 1 && e.polarity != -1 {
            return Err(unwritable(format!("polarity {} is not ±1", e.polarity)));
        }
        self.last_t_ns = Some(e.t_ns);
        self.summary.items += 1;
        self.summary.floored_timestamps += u64::from(e.t_ns % 1000 != 0);
        self.pending.push(*e);
        if self.pending.len() == BLOCK {
            self.flush()?;
        }
        Ok(())
    }
}
