//! Prophesee DAT event files (N-CARS, the Gen1 automotive dataset): a `%` header
//! (`Data file containing CD events`, `Version 2`, `Width`, `Height`, ...), then two bytes, the
//! event type and the event size, then little-endian 8-byte records:
//!
//! | bytes | field |
//! |---|---|
//! | 0..4 | timestamp, µs (`u32`) |
//! | 4..8 | bits `[13:0]` x, `[27:14]` y, `[31:28]` polarity (0 or 1) |
//!
//! Event types: `0x00` Event2d and `0x0C` EventCD carry this layout and are decoded; `0x0E`
//! (external triggers) is reported as unsupported. The size byte must be 8. The 32-bit clock
//! wraps every 2^32 µs (71.6 min): a timestamp more than 2^31 µs below its predecessor is a wrap.
//! Files that say `Version 1` use another record layout and are reported as unsupported; files
//! without a `Version` line are read as version 2.

use std::fs::File;
use std::io::{Cursor, Read, Write};
use std::path::{Path, PathBuf};

use neuspike_schemas::{Event, EventBatch};

use crate::binary::{Chunked, Out, WriteSummary, ns_to_us, us_to_ns};
use crate::error::{FormatError, Location, Result};
use crate::events::{Bounds, EventReader, ReadOptions, Resolution, Sink};
use crate::evt2::check_event;
use crate::header::{AfterHeader, PropheseeHeader, read_header, resolve_resolution};

/// Bytes per record.
pub const RECORD_BYTES: usize = 8;
/// The clock's period: times are stored modulo 2^32 µs (71.6 min). A reader starts counting
/// wraps at 0, so a file's absolute start time is known only modulo this period.
pub const CLOCK_PERIOD_US: u64 = 1 << 32;
/// Event type byte of generic 2D events.
pub const TYPE_EVENT_2D: u8 = 0x00;
/// Event type byte of change-detection events.
pub const TYPE_EVENT_CD: u8 = 0x0C;
/// Event type byte of external triggers.
pub const TYPE_EXT_TRIGGER: u8 = 0x0E;
const COORD_BITS: u32 = 14;
const COORD_MASK: u32 = (1 << COORD_BITS) - 1;
const WRAP_THRESHOLD: u32 = 1 << 31;

/// Whether `(type, size)` is a DAT event type/size pair this format defines.
pub fn is_type_size_pair(event_type: u8, size: u8) -> bool {
    matches!(event_type, TYPE_EVENT_2D | TYPE_EVENT_CD | TYPE_EXT_TRIGGER)
        && usize::from(size) == RECORD_BYTES
}

/// A streaming reader of Prophesee DAT CD event files.
pub struct DatReader<R: Read> {
    header: PropheseeHeader,
    event_type: u8,
    stream: Chunked<AfterHeader<R>>,
    last_t32: Option<u32>,
    wraps: u64,
    sink: Sink,
}

impl DatReader<File> {
    /// Opens a DAT file.
    pub fn open(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Self> {
        let path = path.as_ref();
        let file = crate::open_file(path)?;
        Self::from_reader(file, path, opts)
    }
}

impl<R: Read> DatReader<R> {
    /// Reads a DAT stream from `r`, named `name` in errors.
    pub fn from_reader(mut r: R, name: impl Into<PathBuf>, opts: &ReadOptions) -> Result<Self> {
        let path: PathBuf = name.into();
        let allow_unknown_size = opts.allow_unknown_size;
        let (header, rest) = read_header(&mut r, &path)?;
        if header.lines.is_empty() && rest.is_empty() {
            return Err(FormatError::Empty { path });
        }
        if header.lines.is_empty() {
            return Err(FormatError::Header {
                path,
                what: "no `%` header: not a Prophesee DAT file".into(),
            });
        }
        if let Some(v) = header.dat_version
            && v != 2
        {
            return Err(FormatError::Unsupported {
                path,
                what: format!("DAT `Version {v}` (only version 2 records are decoded)"),
            });
        }
        let offset = header.data_offset;
        let mut stream = Chunked::new(Cursor::new(rest).chain(r), offset);
        stream.fill(2, &path)?;
        let ts = stream.data();
        if ts.len() < 2 {
            return Err(FormatError::Truncated {
                path,
                offset,
                what: "the event type and size bytes after the header are missing".into(),
            });
        }
        let (event_type, size) = (ts[0], ts[1]);
        if !is_type_size_pair(event_type, size) {
            return Err(FormatError::Corrupt {
                path,
                offset,
                what: format!(
                    "event type {event_type:#04x} and size {size} are not a DAT pair \
                     (type 0x00, 0x0C or 0x0E, size 8)"
                ),
            });
        }
        if event_type == TYPE_EXT_TRIGGER {
            return Err(FormatError::Unsupported {
                path,
                what: "DAT of external triggers (type 0x0E), not CD events".into(),
            });
        }
        stream.consume(2);
        let resolution = resolve_resolution(
            header.resolution,
            opts.resolution,
            &path,
            allow_unknown_size,
            "the DAT header has no `% Width` and `% Height` lines",
        )?;
        Ok(DatReader {
            header,
            event_type,
            stream,
            last_t32: None,
            wraps: 0,
            sink: Sink::new(
                path,
                resolution.map_or(Bounds::Unknown, Bounds::Sensor),
                opts,
            ),
        })
    }

    /// The sensor size, when the file or the options give one.
    pub(crate) fn known_resolution(&self) -> Option<Resolution> {
        self.sink.known
    }

    /// The header.
    pub fn header(&self) -> &PropheseeHeader {
        &self.header
    }

    /// The event type byte (`0x00` or `0x0C`).
    pub fn event_type(&self) -> u8 {
        self.event_type
    }
}

impl<R: Read> EventReader for DatReader<R> {
    crate::events::sink_accessors!();

    fn read_into(&mut self, out: &mut EventBatch, max: usize) -> Result<usize> {
        let stream = &mut self.stream;
        let last_t32 = &mut self.last_t32;
        let wraps = &mut self.wraps;
        self.sink.read_with(out, max, |sink, out| {
            while !sink.full() {
                stream.fill(RECORD_BYTES, &sink.path)?;
                let data = stream.data();
                if data.len() < RECORD_BYTES {
                    if !data.is_empty() {
                        return Err(FormatError::Truncated {
                            path: sink.path.clone(),
                            offset: stream.offset(),
                            what: format!("{} byte(s) of an 8-byte DAT record", data.len()),
                        });
                    }
                    sink.finish();
                    return Ok(());
                }
                let consumed = decode(data, stream.offset(), last_t32, wraps, sink, out)?;
                stream.consume(consumed);
            }
            Ok(())
        })
    }
}

/// Decodes whole records of `data` (which start at file offset `at`) until the sink is full;
/// returns the bytes consumed. Blocks of records go straight into the columns
/// ([`decode_fast`]), checked by the sink's column passes ([`Sink::accept_block`]); a block it
/// refuses is taken back and, like every record the fast path leaves, decoded record by record
/// ([`decode_checked`]), which names the fault or repairs it.
fn decode(
    data: &[u8],
    at: u64,
    last_t32: &mut Option<u32>,
    wraps: &mut u64,
    sink: &mut Sink,
    out: &mut EventBatch,
) -> Result<usize> {
    let mut state = (*last_t32, *wraps);
    let decoded = sink.decode_blocks::<_, RECORD_BYTES>(
        data,
        at,
        &mut state,
        out,
        |(last, wraps), records, out, max| decode_fast(records, last, *wraps, out, max),
        |(last, wraps), records, at, sink, out| decode_checked(records, at, last, wraps, sink, out),
    );
    // The state stands after the records decoded, an error's included.
    (*last_t32, *wraps) = state;
    decoded
}

/// A record's two words: the time in µs (32 bits) and the packed coordinates and polarity.
#[inline(always)]
fn words(rec: &[u8]) -> (u32, u32) {
    (
        u32::from_le_bytes([rec[0], rec[1], rec[2], rec[3]]),
        u32::from_le_bytes([rec[4], rec[5], rec[6], rec[7]]),
    )
}

/// The fast path: decodes the records at the start of `data` straight into `out`'s columns, at
/// most `max_events`, and returns the bytes consumed (`last_t32` then stands after them). It
/// stops before any record the checked path must see: the file's first, a clock wrap, a polarity
/// other than 0 or 1. Coordinates and the time order are for the sink to check.
#[inline(never)]
fn decode_fast(
    data: &[u8],
    last_t32: &mut Option<u32>,
    wraps: u64,
    out: &mut EventBatch,
    max_events: usize,
) -> usize {
    let Some(mut last) = *last_t32 else {
        return 0;
    };
    // Every time before the next wrap fits `i64` ns: checked once, here.
    let fits = (wraps + 1)
        .checked_mul(CLOCK_PERIOD_US)
        .and_then(|end_us| end_us.checked_mul(1000))
        .is_some_and(|end_ns| i64::try_from(end_ns).is_ok());
    if !fits {
        return 0;
    }
    let wrap_base_ns = (wraps * CLOCK_PERIOD_US) as i64 * 1000;
    let records = (data.len() / RECORD_BYTES).min(max_events);
    let start = out.len();
    let cap = start + records;
    out.resize(cap);
    let (ts, xs, ys, ps) = (
        &mut out.t_ns[start..cap],
        &mut out.x[start..cap],
        &mut out.y[start..cap],
        &mut out.polarity[start..cap],
    );
    let mut n = 0;
    for rec in data.chunks_exact(RECORD_BYTES).take(records) {
        let (t32, w) = words(rec);
        let polarity = w >> (2 * COORD_BITS);
        if polarity > 1 || (t32 < last && last - t32 > WRAP_THRESHOLD) {
            break;
        }
        last = t32;
        // Coordinates of 14 bits fit u16; polarity 0 is -1, 1 is +1.
        ts[n] = wrap_base_ns + i64::from(t32) * 1000;
        xs[n] = (w & COORD_MASK) as u16;
        ys[n] = ((w >> COORD_BITS) & COORD_MASK) as u16;
        ps[n] = 2 * polarity as i8 - 1;
        n += 1;
    }
    out.truncate(start + n);
    *last_t32 = Some(last);
    n * RECORD_BYTES
}

/// The checked path: decodes whole records of `data` (which start at file offset `at`) one by
/// one, each event through [`Sink::emit`], until the sink is full; returns the bytes consumed.
fn decode_checked(
    data: &[u8],
    at: u64,
    last_t32: &mut Option<u32>,
    wraps: &mut u64,
    sink: &mut Sink,
    out: &mut EventBatch,
) -> Result<usize> {
    let mut consumed = 0usize;
    for rec in data.chunks_exact(RECORD_BYTES) {
        if sink.full() {
            break;
        }
        let at = at + consumed as u64;
        consumed += RECORD_BYTES;
        let (t32, w) = words(rec);
        if let Some(last) = *last_t32
            && t32 < last
            && last - t32 > WRAP_THRESHOLD
        {
            *wraps += 1;
            sink.stats.time_wraps += 1;
        }
        *last_t32 = Some(t32);
        let polarity = w >> (2 * COORD_BITS);
        if polarity > 1 {
            return Err(FormatError::Polarity {
                path: sink.path.clone(),
                at: Location::Byte(at),
                value: i64::from(polarity),
            });
        }
        let t_ns = us_to_ns((*wraps << 32) | u64::from(t32), &sink.path, at)?;
        sink.emit(
            out,
            t_ns,
            w & COORD_MASK,
            (w >> COORD_BITS) & COORD_MASK,
            polarity == 1,
            Location::Byte(at),
        )?;
    }
    Ok(consumed)
}

/// Writes events as a Prophesee DAT file of CD events (type `0x0C`, version 2). Times are floored
/// to microseconds and stored modulo 2^32 µs ([`CLOCK_PERIOD_US`]), as the sensor's clock wraps;
/// a gap of 2^31 µs or more between two events cannot be told from a wrap and is refused. Times
/// at or past the first period come back modulo [`CLOCK_PERIOD_US`] at the start of the file.
pub struct DatWriter<W: Write> {
    out: Out<W>,
    resolution: Resolution,
    last_t_us: Option<u64>,
    summary: WriteSummary,
}

impl<W: Write> DatWriter<W> {
    /// Starts a file on `w` (named `name` in errors) for a sensor of `resolution`.
    pub fn new(w: W, name: impl Into<PathBuf>, resolution: Resolution) -> Result<Self> {
        let mut out = Out::new(w, name.into());
        if u32::from(resolution.width) > COORD_MASK + 1
            || u32::from(resolution.height) > COORD_MASK + 1
        {
            return Err(out.unwritable(
                0,
                format!("resolution {resolution} exceeds DAT's 16384x16384"),
            ));
        }
        let header = format!(
            "% Data file containing CD events\n% Version 2\n% Width {}\n% Height {}\n",
            resolution.width, resolution.height
        );
        out.put(header.as_bytes())?;
        out.put(&[TYPE_EVENT_CD, RECORD_BYTES as u8])?;
        Ok(DatWriter {
            out,
            resolution,
            last_t_us: None,
            summary: WriteSummary::default(),
        })
    }

    /// Appends one event; events must come in non-decreasing time order.
    pub fn write_event(&mut self, e: &Event) -> Result<()> {
        let index = self.summary.items;
        let (t_us, floored) = ns_to_us(&self.out, index, e.t_ns)?;
        check_event(&self.out, index, e, self.resolution, self.last_t_us, t_us)?;
        if let Some(last) = self.last_t_us
            && t_us - last >= u64::from(WRAP_THRESHOLD)
        {
            return Err(self.out.unwritable(
                index,
                format!(
                    "a gap of {} us after the previous event is too long for a 32-bit clock",
                    t_us - last
                ),
            ));
        }
        let p = u32::from(e.polarity > 0);
        let w = u32::from(e.x) | (u32::from(e.y) << COORD_BITS) | (p << (2 * COORD_BITS));
        self.out.put(&(t_us as u32).to_le_bytes())?;
        self.out.put(&w.to_le_bytes())?;
        self.last_t_us = Some(t_us);
        self.summary.items += 1;
        self.summary.floored_timestamps += u64::from(floored);
        Ok(())
    }

    /// Flushes and returns the sink and what was written.
    pub fn finish(self) -> Result<(W, WriteSummary)> {
        self.out.finish_with(self.summary)
    }
}

impl<W: Write> crate::EventWriter for DatWriter<W> {
    fn write_event(&mut self, e: &Event) -> Result<()> {
        DatWriter::write_event(self, e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::fast_vs_checked::{assert_same, decode_all, options};
    use proptest::prelude::*;

    /// Records with coordinates a little past the 40x30 sensor, now and then a bad polarity,
    /// times that mostly rise (sometimes step back, sometimes wrap).
    fn records() -> impl Strategy<Value = Vec<u8>> {
        let record = (
            0u32..4,
            0u32..44,
            0u32..34,
            prop_oneof![20 => 0u32..2, 1 => 2u32..16],
        );
        proptest::collection::vec(record, 0..3000).prop_map(|list| {
            let mut t = 0u32;
            let mut out = Vec::new();
            for (i, (step, x, y, p)) in list.into_iter().enumerate() {
                t = match i % 211 {
                    7 => t.wrapping_sub(2),
                    100 => t.wrapping_add(WRAP_THRESHOLD + 9),
                    _ => t.wrapping_add(step),
                };
                out.extend_from_slice(&t.to_le_bytes());
                out.extend_from_slice(&(p << 28 | y << COORD_BITS | x).to_le_bytes());
            }
            out
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]
        /// The fast path gives what the checked path gives, record for record: the same events,
        /// statistics and error, whatever the requests' sizes and the buffers' boundaries.
        #[test]
        fn the_fast_path_matches_the_checked_one(
            data in records(),
            max in 1usize..5000,
            piece in prop::sample::select(vec![8usize, 13, 64, 1 << 20]),
            clamp in any::<bool>(),
        ) {
            let opts = options(clamp, false);
            let (mut last, mut wraps) = (None, 0u64);
            let fast = decode_all(&data, max, piece, &opts, |b, at, sink, out| {
                decode(b, at, &mut last, &mut wraps, sink, out)
            });
            let (mut last, mut wraps) = (None, 0u64);
            let checked = decode_all(&data, max, piece, &opts, |b, at, sink, out| {
                decode_checked(b, at, &mut last, &mut wraps, sink, out)
            });
            assert_same(&fast, &checked)?;
        }
    }

    #[test]
    fn a_clock_near_the_end_of_i64_leaves_the_fast_path() {
        let rec = [
            5u32.to_le_bytes(),
            (1u32 << 28 | 2 << COORD_BITS | 3).to_le_bytes(),
        ]
        .concat();
        let mut out = EventBatch::default();
        let wraps = (i64::MAX / 1000) as u64 >> 32;
        assert_eq!(decode_fast(&rec, &mut Some(0), wraps, &mut out, 10), 0);
        assert_eq!(decode_fast(&rec, &mut Some(0), wraps - 1, &mut out, 10), 8);
        assert_eq!((out.x[0], out.y[0], out.polarity[0]), (3, 2, 1));
        // The first record of a file has no predecessor to tell a wrap: the checked path's.
        assert_eq!(decode_fast(&rec, &mut None, 0, &mut out, 10), 0);
    }
}
