//! Prophesee EVT 3.0: 16-bit little-endian words, the type in the 4 most significant bits. The
//! encoding is stateful: a word sets the row, the time or the base column that later words use.
//!
//! | type | name | payload |
//! |---|---|---|
//! | `0000` | EVT_ADDR_Y | `[10:0]` row, `[11]` system type (ignored) |
//! | `0010` | EVT_ADDR_X | `[10:0]` column, `[11]` polarity: one event |
//! | `0011` | VECT_BASE_X | `[10:0]` base column, `[11]` polarity for the vectors after it |
//! | `0100` | VECT_12 | `[11:0]` valid bits: events at base + i; base += 12 |
//! | `0101` | VECT_8 | `[7:0]` valid bits: events at base + i; base += 8 |
//! | `0110` | EVT_TIME_LOW | `[11:0]` bits 0..11 of the µs time |
//! | `0111` | CONTINUED_4 | extra data (skipped, counted) |
//! | `1000` | EVT_TIME_HIGH | `[11:0]` bits 12..23 of the µs time |
//! | `1010` | EXT_TRIGGER | `[0]` value, `[11:8]` channel (counted) |
//! | `1110` | OTHERS | extensions (skipped, counted) |
//! | `1111` | CONTINUED_12 | extra data (skipped, counted) |
//!
//! Other types are reserved ([`crate::UnknownWords`]).
//!
//! Time: `time_high << 12 | time_low` µs on a 24-bit clock that wraps every 2^24 µs (16.8 s). A
//! `TIME_HIGH` at least 2^11 steps below its predecessor is a wrap (adds 2^24 µs), as in
//! Prophesee's decoder; a `TIME_HIGH` that changes the high bits resets the low bits to 0 until
//! the next `TIME_LOW`. A `TIME_LOW` below the previous one under the same `TIME_HIGH` is taken
//! literally, without an implied carry (Prophesee's convention too): the events after it are
//! earlier than those before, and [`crate::Disorder`] decides (error by default, or clamp and
//! count). Events before the first `TIME_HIGH` or the first `EVT_ADDR_Y`, and vector words before
//! any `VECT_BASE_X`, are dropped and counted in
//! [`crate::ReadStats::events_without_time_base`].
//!
//! Columns: each vector word moves the base column on by 12 or 8, so a long run of them can
//! carry it past the sensor and, on a hostile file, towards `u32::MAX`. The base saturates and
//! every column is computed with checked arithmetic: an event at or past the sensor's width is
//! an error ([`crate::FormatError::OutOfBounds`], naming its byte and the column, `4294967295`
//! when the column does not fit a `u32`), never a column that wrapped back onto the sensor.

use std::io::Write;

use neuspike_schemas::{Event, EventBatch};

use crate::binary::{Out, WriteSummary, ns_to_us, us_to_ns};
use crate::error::{Location, Result};
use crate::events::{Resolution, Sink};
use crate::evt2::{check_event, raw_header};

/// Bytes per word.
pub const WORD_BYTES: usize = 2;
/// The sensor clock's period: times are carried modulo 2^24 µs (16.8 s). A file's absolute start
/// time is therefore known only modulo this period: a reader starts counting wraps at 0.
pub const CLOCK_PERIOD_US: u64 = 1 << 24;
/// Word types.
pub mod word {
    /// Row.
    pub const ADDR_Y: u8 = 0x0;
    /// Column and polarity of one event.
    pub const ADDR_X: u8 = 0x2;
    /// Base column and polarity of the vectors after it.
    pub const VECT_BASE_X: u8 = 0x3;
    /// 12 events' valid bits.
    pub const VECT_12: u8 = 0x4;
    /// 8 events' valid bits.
    pub const VECT_8: u8 = 0x5;
    /// Bits 0..11 of the time.
    pub const TIME_LOW: u8 = 0x6;
    /// 4 bits of extra data.
    pub const CONTINUED_4: u8 = 0x7;
    /// Bits 12..23 of the time.
    pub const TIME_HIGH: u8 = 0x8;
    /// External trigger.
    pub const EXT_TRIGGER: u8 = 0xA;
    /// Extensions.
    pub const OTHERS: u8 = 0xE;
    /// 12 bits of extra data.
    pub const CONTINUED_12: u8 = 0xF;
}
const COORD_MASK: u32 = (1 << 11) - 1;
const POLARITY_BIT: u32 = 1 << 11;
const TIME_BITS: u32 = 12;
const TIME_MASK: u32 = (1 << TIME_BITS) - 1;
/// A `TIME_HIGH` this many steps below its predecessor (or more) is a wrap.
const WRAP_THRESHOLD: u32 = 1 << (TIME_BITS - 1);

/// The word types [`Evt3Decoder::decode_fast`] decodes, as a bit set over the 16 types.
const FAST_KINDS: u16 = ROW_COLUMN_LOW
    | 1 << word::VECT_BASE_X
    | 1 << word::VECT_12
    | 1 << word::VECT_8
    | 1 << word::TIME_HIGH;
/// The types of the fast path's branch-free words: rows, columns and low time bits.
const ROW_COLUMN_LOW: u16 = 1 << word::ADDR_Y | 1 << word::ADDR_X | 1 << word::TIME_LOW;

/// The type nibbles of a `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group read as one
/// little-endian `u64`, and the mask that selects them.
const GROUP_KINDS: u64 = (word::VECT_BASE_X as u64) << 12
    | (word::VECT_12 as u64) << 28
    | (word::VECT_12 as u64) << 44
    | (word::VECT_8 as u64) << 60;
const GROUP_KINDS_MASK: u64 = 0xF000_F000_F000_F000;

/// Decoder state across buffers.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Evt3Decoder {
    high: Option<u32>,
    low: u32,
    wraps: u64,
    y: Option<u32>,
    base_x: Option<u32>,
    base_on: bool,
}

impl Evt3Decoder {
    fn t_us(&self) -> Option<u64> {
        let high = self.high?;
        Some((self.wraps << (2 * TIME_BITS)) | (u64::from(high) << TIME_BITS) | u64::from(self.low))
    }

    /// Decodes whole words of `bytes` (which start at file offset `offset`) until the sink is
    /// full; returns the bytes consumed.
    ///
    /// Runs of ordinary words go through [`Evt3Decoder::decode_fast`], a block at a time, and
    /// the sink checks each block's events in column passes ([`Sink::accept_block`]). A block
    /// the sink refuses is taken back (events and decoder state) and decoded again by
    /// [`Evt3Decoder::decode_checked`], word by word, which names the fault or repairs it; so
    /// does every word the fast path leaves.
    pub(crate) fn decode(
        &mut self,
        bytes: &[u8],
        offset: u64,
        sink: &mut Sink,
        out: &mut EventBatch,
    ) -> Result<usize> {
        let (width, _) = sink.bounds();
        sink.decode_blocks::<_, WORD_BYTES>(
            bytes,
            offset,
            self,
            out,
            |d: &mut Self, b: &[u8], out: &mut EventBatch, max| d.decode_fast(b, width, out, max),
            |d, b, at, sink, out| d.decode_checked(b, at, sink, out),
        )
    }

    /// The fast path: decodes the ordinary words at the start of `bytes` (rows, columns,
    /// vectors, times without a wrap) straight into `out`'s columns, at most `max_events`
    /// events, and returns the bytes consumed; its state then stands after them. It stops before
    /// any word the checked path must see: another type, a clock wrap, a column at or past
    /// `width`, an event without a time base, a row or a base column, or a vector with no room
    /// left. Rows and the time order are for the sink to check.
    ///
    /// Rows, columns and low time bits (about 75-80% of a file's words, in an order no branch
    /// predictor learns) take one tight loop over each run of them, without a branch on their
    /// type: each writes a candidate event at the next free slot, kept only for a column word,
    /// and updates the row and the time by selects. Base columns, vectors and high time bits take
    /// a branch; a whole `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group (a 32-pixel vector, as
    /// our writer emits it) is read as one `u64` and its 32 valid bits walked in one loop.
    #[inline(never)]
    fn decode_fast(
        &mut self,
        bytes: &[u8],
        width: u32,
        out: &mut EventBatch,
        max_events: usize,
    ) -> usize {
        use std::hint::select_unpredictable as select;
        let (Some(mut high), Some(mut y)) = (self.high, self.y) else {
            return 0;
        };
        // Every time before the next wrap fits `i64` ns: checked once, here.
        let Some(wrap_base_ns) = (self.wraps + 1)
            .checked_mul(CLOCK_PERIOD_US)
            .and_then(|end_us| i64::try_from(end_us).ok())
            .and_then(|end_us| end_us.checked_mul(1000))
            .map(|_| (self.wraps * CLOCK_PERIOD_US) as i64 * 1000)
        else {
            return 0;
        };
        // A word the checked path takes comes first: no block (nor its zeroed room) for it.
        // (The type is the top 4 bits of the little-endian word's second byte.)
        if bytes
            .get(1)
            .is_none_or(|&b| FAST_KINDS >> (b >> 4) & 1 == 0)
        {
            return 0;
        }
        let (mut base_x, mut base_on) = (self.base_x, self.base_on);
        // The time of `high` with low bits 0, and the time of the events, in ns.
        let mut high_ns = wrap_base_ns + i64::from(high << TIME_BITS) * 1000;
        let mut t_ns = high_ns + i64::from(self.low) * 1000;
        // The columns are grown by the block's room first and cut back after: each event is then
        // four stores, without a capacity check each.
        let start = out.len();
        let cap = start + max_events;
        out.resize(cap);
        let (ts, xs, ys, ps) = (
            &mut out.t_ns[..cap],
            &mut out.x[..cap],
            &mut out.y[..cap],
            &mut out.polarity[..cap],
        );
        let mut n = start;
        let mut used = 0usize;
        // x < width <= 65,536 and y < 2,048 here: both fit u16.
        macro_rules! push {
            ($t_ns:expr, $x:expr, $y:expr, $on:expr) => {{
                ts[n] = $t_ns;
                xs[n] = $x as u16;
                ys[n] = $y as u16;
                ps[n] = if $on { 1 } else { -1 };
                n += 1;
            }};
        }
        let words = bytes.len() / WORD_BYTES;
        while used < words {
            // Room for the most one word gives: a `VECT_12` with every bit valid.
            if n + 12 > cap {
                break;
            }
            let at = used * WORD_BYTES;
            let word = u16::from_le_bytes([bytes[at], bytes[at + 1]]);
            let kind = (word >> 12) as u8;
            let payload = u32::from(word) & 0xFFF;
            let coord = payload & COORD_MASK;
            let on = payload & POLARITY_BIT != 0;
            if ROW_COLUMN_LOW >> kind & 1 == 1 {
                // A run of them, as far as the room left goes (each gives at most one event).
                // A column past the sensor is kept here: the sink refuses the block for it, and
                // the checked path decodes the block again (a branch on it here would be one on
                // the word's type).
                let stop = words.min(used + (cap - n));
                for w in bytes[at..stop * WORD_BYTES].chunks_exact(WORD_BYTES) {
                    let word = u16::from_le_bytes([w[0], w[1]]);
                    let kind = (word >> 12) as u8;
                    if ROW_COLUMN_LOW >> kind & 1 == 0 {
                        break;
                    }
                    let payload = u32::from(word) & 0xFFF;
                    let coord = payload & COORD_MASK;
                    ts[n] = t_ns;
                    xs[n] = coord as u16;
                    ys[n] = y as u16;
                    // Bit 11, the polarity, as +1 or -1.
                    ps[n] = (payload >> 10 & 2) as i8 - 1;
                    n += usize::from(kind == word::ADDR_X);
                    y = select(kind == word::ADDR_Y, coord, y);
                    let t_low = high_ns + i64::from(payload) * 1000;
                    t_ns = select(kind == word::TIME_LOW, t_low, t_ns);
                    used += 1;
                }
                continue;
            }
            match kind {
                word::VECT_BASE_X => {
                    // The usual group, `VECT_BASE_X, VECT_12, VECT_12, VECT_8`, as one 32-bit
                    // set of valid bits: one loop over its events instead of three.
                    if let Some(&group) = bytes[at..].first_chunk::<8>()
                        && n + 32 <= cap
                    {
                        let g = u64::from_le_bytes(group);
                        let valid = (g >> 16 & 0xFFF) as u32
                            | ((g >> 32 & 0xFFF) as u32) << 12
                            | ((g >> 48 & 0xFF) as u32) << 24;
                        if g & GROUP_KINDS_MASK == GROUP_KINDS
                            && (valid == 0 || coord + (31 - valid.leading_zeros()) < width)
                        {
                            let mut valid = valid;
                            while valid != 0 {
                                let i = valid.trailing_zeros();
                                valid &= valid - 1;
                                push!(t_ns, coord + i, y, on);
                            }
                            (base_x, base_on) = (Some(coord + VECTOR_SPAN as u32), on);
                            used += 4;
                            continue;
                        }
                    }
                    (base_x, base_on) = (Some(coord), on)
                }
                word::VECT_12 | word::VECT_8 => {
                    let Some(base) = base_x else { break };
                    let k = if kind == word::VECT_12 { 12 } else { 8 };
                    let mut valid = payload & ((1 << k) - 1);
                    // The last valid column, unwrapped: on the sensor, or the checked path names it.
                    if valid != 0
                        && base
                            .checked_add(31 - valid.leading_zeros())
                            .is_none_or(|last| last >= width)
                    {
                        break;
                    }
                    while valid != 0 {
                        let i = valid.trailing_zeros();
                        valid &= valid - 1;
                        push!(t_ns, base + i, y, base_on);
                    }
                    base_x = Some(base.saturating_add(k));
                }
                word::TIME_HIGH => {
                    if payload < high && high - payload >= WRAP_THRESHOLD {
                        break;
                    }
                    // The low bits stay under the same high bits, and go to 0 under new ones.
                    let low_ns = if payload == high { t_ns - high_ns } else { 0 };
                    high = payload;
                    high_ns = wrap_base_ns + i64::from(high << TIME_BITS) * 1000;
                    t_ns = high_ns + low_ns;
                }
                _ => break,
            }
            used += 1;
        }
        out.truncate(n);
        // `t_ns` is `high_ns` plus the low bits in µs, so the division is exact.
        let low = ((t_ns - high_ns) / 1000) as u32;
        (self.high, self.y, self.low) = (Some(high), Some(y), low);
        (self.base_x, self.base_on) = (base_x, base_on);
        used * WORD_BYTES
    }

    /// The checked path: decodes whole words of `bytes` (which start at file offset `offset`)
    /// one by one, each event through [`Sink::emit`], until the sink is full; returns the bytes
    /// consumed.
    fn decode_checked(
        &mut self,
        bytes: &[u8],
        offset: u64,
        sink: &mut Sink,
        out: &mut EventBatch,
    ) -> Result<usize> {
        let mut consumed = 0usize;
        for w in bytes.chunks_exact(WORD_BYTES) {
            if sink.full() {
                break;
            }
            let word = u16::from_le_bytes([w[0], w[1]]);
            let at = offset + consumed as u64;
            consumed += WORD_BYTES;
            let kind = (word >> 12) as u8;
            let payload = u32::from(word) & 0xFFF;
            match kind {
                word::ADDR_Y => self.y = Some(payload & COORD_MASK),
                word::ADDR_X => match (self.t_us(), self.y) {
                    (Some(t_us), Some(y)) => {
                        let t_ns = us_to_ns(t_us, &sink.path, at)?;
                        let on = payload & POLARITY_BIT != 0;
                        sink.emit(out, t_ns, payload & COORD_MASK, y, on, Location::Byte(at))?;
                    }
                    _ => sink.stats.events_without_time_base += 1,
                },
                word::VECT_BASE_X => {
                    self.base_x = Some(payload & COORD_MASK);
                    self.base_on = payload & POLARITY_BIT != 0;
                }
                word::VECT_12 | word::VECT_8 => {
                    let n = if kind == word::VECT_12 { 12 } else { 8 };
                    let mut valid = payload & ((1 << n) - 1);
                    match (self.t_us(), self.y, self.base_x) {
                        (Some(t_us), Some(y), Some(base)) => {
                            let t_ns = us_to_ns(t_us, &sink.path, at)?;
                            while valid != 0 {
                                let i = valid.trailing_zeros();
                                valid &= valid - 1;
                                // Saturated, never wrapped: u32::MAX is off every sensor.
                                sink.emit(
                                    out,
                                    t_ns,
                                    base.saturating_add(i),
                                    y,
                                    self.base_on,
                                    Location::Byte(at),
                                )?;
                            }
                        }
                        _ => sink.stats.events_without_time_base += u64::from(valid.count_ones()),
                    }
                    if let Some(b) = &mut self.base_x {
                        *b = b.saturating_add(n);
                    }
                }
                word::TIME_LOW => self.low = payload,
                word::TIME_HIGH => {
                    if let Some(h) = self.high {
                        if payload < h && h - payload >= WRAP_THRESHOLD {
                            self.wraps += 1;
                            sink.stats.time_wraps += 1;
                        }
                        if payload != h {
                            self.low = 0;
                        }
                    }
                    self.high = Some(payload);
                }
                word::EXT_TRIGGER => sink.stats.triggers += 1,
                word::CONTINUED_4 | word::CONTINUED_12 | word::OTHERS => {
                    sink.stats.skipped_words += 1;
                }
                _ => sink.unknown_word(at, "EVT 3.0", kind, u32::from(word))?,
            }
        }
        Ok(consumed)
    }
}

pub use crate::events::MAX_EVENTS_PER_PACKET;

/// Pixels one `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group covers.
const VECTOR_SPAN: u16 = 32;

/// EVT 3.0 words that arrive in packets (a ROS 2 `EventPacket`, a network buffer): the
/// decoder's state (time, row, base column) carries from one packet to the next, as a camera's
/// word stream continues across its buffers. Errors name `name` and the byte offset counted over
/// every packet so far; after one, the stream is over.
pub struct Evt3Stream {
    decoder: Evt3Decoder,
    sink: Sink,
    offset: u64,
    max_events: usize,
}

/// Bytes of a packet decoded at a time, the events checked against the packet's limit between
/// them: at most 6 events a byte, so a packet stops within 393,216 events of its limit.
const STREAM_SLICE_BYTES: usize = 1 << 16;

impl Evt3Stream {
    /// A stream from a sensor of `resolution`, named `name` in errors.
    pub fn new(
        name: impl Into<std::path::PathBuf>,
        resolution: Resolution,
        opts: &crate::ReadOptions,
    ) -> Self {
        Evt3Stream {
            decoder: Evt3Decoder::default(),
            sink: Sink::new(name.into(), crate::events::Bounds::Sensor(resolution), opts),
            offset: 0,
            max_events: opts.max_events_per_packet,
        }
    }

    /// Decodes the whole words of `packet`, appending their events to `out`; returns how many.
    /// The packet is decoded a slice at a time and refused once it holds more events than
    /// [`crate::ReadOptions::max_events_per_packet`]: as with every error here, the events
    /// decoded before it are returned first and the error on the next call.
    ///
    /// # Errors
    /// A packet of an odd length, an event outside the sensor, time running backwards (under
    /// the default [`crate::Disorder::Error`]), or an undefined word type (under the default
    /// [`crate::UnknownWords::Error`]).
    pub fn decode(&mut self, packet: &[u8], out: &mut EventBatch) -> Result<usize> {
        if !packet.len().is_multiple_of(WORD_BYTES) {
            return Err(crate::FormatError::Truncated {
                path: self.sink.path.clone(),
                offset: self.offset + packet.len() as u64 - 1,
                what: format!("an EVT 3.0 packet of {} bytes (odd)", packet.len()),
            });
        }
        let Evt3Stream {
            decoder,
            sink,
            offset,
            max_events,
        } = self;
        let (start, max_events) = (*offset, *max_events);
        let n = sink.read_with(out, usize::MAX, |sink, out| {
            let first = out.len();
            let mut pos = 0usize;
            while pos < packet.len() {
                let end = pos.saturating_add(STREAM_SLICE_BYTES).min(packet.len());
                let used = decoder.decode(&packet[pos..end], start + pos as u64, sink, out)?;
                if used == 0 {
                    break;
                }
                pos += used;
                if out.len() - first > max_events {
                    return Err(crate::FormatError::Corrupt {
                        path: sink.path.clone(),
                        offset: start + pos as u64,
                        what: format!(
                            "a packet of {} bytes holds more than {max_events} events, the most \
                             a packet may hold (ReadOptions::max_events_per_packet)",
                            packet.len()
                        ),
                    });
                }
            }
            Ok(())
        })?;
        *offset += packet.len() as u64;
        Ok(n)
    }

    /// What was decoded and repaired so far.
    pub fn stats(&self) -> &crate::ReadStats {
        &self.sink.stats
    }
}

/// Writes events as a Prophesee RAW EVT 3.0 file: a `%` header, then `TIME_HIGH`/`TIME_LOW`/
/// `EVT_ADDR_Y` words when the time or row changes, and the events in as few words as this
/// writer finds (the format's purpose is compactness). Consecutive events that share time, row
/// and polarity with increasing columns form a run; in a run, an event with at least two more
/// within the 12 columns from it starts a vector, `VECT_BASE_X` then a `VECT_12` (or a `VECT_8`
/// when its events lie in the first 8 columns) for each stretch of 12 columns that holds at
/// least two of the run's events (two events in one word, where `EVT_ADDR_X` takes one each);
/// every other event is one `EVT_ADDR_X`. A dense 32-column run is thus the usual
/// `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group. [`Evt3Writer::with_full_vector_groups`] writes
/// the larger encoding of earlier versions instead.
///
/// Times are floored to microseconds and wrap every 2^24 µs ([`CLOCK_PERIOD_US`]), as on the
/// sensor, with extra `TIME_HIGH` words over long gaps so that a reader can always tell a wrap
/// from a jump. The format has no field for whole periods, so reading the file back gives times
/// modulo [`CLOCK_PERIOD_US`] at its start (later wraps are undone).
pub struct Evt3Writer<W: Write> {
    out: Out<W>,
    resolution: Resolution,
    last_t_us: Option<u64>,
    last_high: Option<u64>,
    last_low: Option<u32>,
    last_y: Option<u16>,
    full_groups: bool,
    summary: WriteSummary,
}

impl<W: Write> Evt3Writer<W> {
    /// Starts a file on `w` (named `name` in errors) for a sensor of `resolution` (at most
    /// 2048x2048, the format's limit).
    pub fn new(w: W, name: impl Into<std::path::PathBuf>, resolution: Resolution) -> Result<Self> {
        let mut out = Out::new(w, name.into());
        if u32::from(resolution.width) > COORD_MASK + 1
            || u32::from(resolution.height) > COORD_MASK + 1
        {
            return Err(out.unwritable(
                0,
                format!("resolution {resolution} exceeds EVT 3.0's 2048x2048"),
            ));
        }
        out.put(raw_header("3.0", "EVT3", resolution).as_bytes())?;
        Ok(Evt3Writer {
            out,
            resolution,
            last_t_us: None,
            last_high: None,
            last_low: None,
            last_y: None,
            full_groups: false,
            summary: WriteSummary::default(),
        })
    }

    /// Writes every run of at least two events within 32 columns as one whole
    /// `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group (four words, whatever it carries), as this
    /// writer did before it looked for the shortest words: larger files (14% on the real events
    /// of `bench_read`), kept to time and test readers on streams heavy with vector groups.
    pub fn with_full_vector_groups(mut self) -> Self {
        self.full_groups = true;
        self
    }

    fn put(&mut self, kind: u8, payload: u32) -> Result<()> {
        let w = (u16::from(kind) << 12) | (payload & 0xFFF) as u16;
        self.out.put(&w.to_le_bytes())
    }

    /// Checks event `e` (the `index`-th written) and emits the time and row words it needs.
    fn prepare(&mut self, e: &Event) -> Result<u64> {
        let index = self.summary.items;
        let (t_us, floored) = ns_to_us(&self.out, index, e.t_ns)?;
        check_event(&self.out, index, e, self.resolution, self.last_t_us, t_us)?;
        self.summary.floored_timestamps += u64::from(floored);
        let high = t_us >> TIME_BITS;
        // Keep consecutive TIME_HIGH words less than half the clock range apart.
        const STEP: u64 = 1 << (TIME_BITS - 2);
        if let Some(mut last) = self.last_high {
            while high - last > STEP {
                last += STEP;
                self.put(word::TIME_HIGH, last as u32)?;
            }
        }
        // A TIME_HIGH word sets the upper bits only: the format does not say it clears the lower
        // ones (neuspike's reader clears them; Prophesee's and evlib's keep the last TIME_LOW), so
        // a TIME_LOW word always follows it and every reader agrees.
        if self.last_high != Some(high) {
            self.put(word::TIME_HIGH, high as u32)?;
            self.last_high = Some(high);
            self.last_low = None;
        }
        let low = (t_us as u32) & TIME_MASK;
        if self.last_low != Some(low) {
            self.put(word::TIME_LOW, low)?;
            self.last_low = Some(low);
        }
        if self.last_y != Some(e.y) {
            self.put(word::ADDR_Y, u32::from(e.y))?;
            self.last_y = Some(e.y);
        }
        self.last_t_us = Some(t_us);
        Ok(t_us)
    }

    /// Checks events `from..to` of `b`, vector events after the first of their vector (which
    /// [`Self::prepare`] checked), in the vector word whose events start at `word_start` (so
    /// event `word_start` is the `summary.items`-th written): bounds and polarity; their time
    /// and row are the first's. Counts floored times.
    fn check_vector_rest(
        &mut self,
        b: &EventBatch,
        word_start: usize,
        from: usize,
        to: usize,
    ) -> Result<()> {
        for k in from..to {
            let ek = b.get(k);
            let index = self.summary.items + (k - word_start) as u64;
            check_event(&self.out, index, &ek, self.resolution, None, 0)?;
        }
        if b.t_ns[word_start] % 1000 != 0 {
            self.summary.floored_timestamps += (to - from) as u64;
        }
        Ok(())
    }

    /// Appends one event; events must come in non-decreasing time order.
    pub fn write_event(&mut self, e: &Event) -> Result<()> {
        self.prepare(e)?;
        self.put(word::ADDR_X, u32::from(e.x) | polarity_bit(e.polarity))?;
        self.summary.items += 1;
        Ok(())
    }

    /// Appends every event of a batch, vectorising runs (see [`Evt3Writer`]).
    pub fn write_batch(&mut self, b: &EventBatch) -> Result<()> {
        let n = b.len();
        let mut i = 0;
        while i < n {
            let e = b.get(i);
            // The run of events after `e`: same time, row and polarity, columns increasing
            // (within one group's 32 columns for full groups).
            let mut j = i + 1;
            while j < n
                && b.t_ns[j] == e.t_ns
                && b.y[j] == e.y
                && b.polarity[j] == e.polarity
                && b.x[j] > b.x[j - 1]
                && (!self.full_groups || b.x[j] - e.x < VECTOR_SPAN)
            {
                j += 1;
            }
            if self.full_groups {
                self.write_group(b, i, j)?;
            } else {
                self.write_run(b, i, j)?;
            }
            i = j;
        }
        Ok(())
    }

    /// Writes the run `i..j` of `b` (see [`Evt3Writer::write_batch`]) in the shortest words.
    fn write_run(&mut self, b: &EventBatch, i: usize, j: usize) -> Result<()> {
        let pol = polarity_bit(b.polarity[i]);
        // `k + m < j && x[k + m] < x + span`: the run has m more events within `span` columns
        // from x (the columns increase strictly).
        let more_within =
            |k: usize, m: usize, x: u32, span: u32| k + m < j && u32::from(b.x[k + m]) < x + span;
        let mut k = i;
        while k < j {
            let x0 = u32::from(b.x[k]);
            if !more_within(k, 2, x0, 12) {
                self.write_event(&b.get(k))?;
                k += 1;
                continue;
            }
            let first = k;
            self.prepare(&b.get(k))?;
            self.put(word::VECT_BASE_X, x0 | pol)?;
            let mut base = x0;
            loop {
                let end = k + b.x[k..j].partition_point(|&x| u32::from(x) < base + 12);
                let (kind, span) = if u32::from(b.x[end - 1]) < base + 8 {
                    (word::VECT_8, 8)
                } else {
                    (word::VECT_12, 12)
                };
                self.check_vector_rest(b, k, k.max(first + 1), end)?;
                let mask = b.x[k..end]
                    .iter()
                    .fold(0u32, |m, &x| m | 1 << (u32::from(x) - base));
                self.put(kind, mask)?;
                self.summary.items += (end - k) as u64;
                k = end;
                base += span;
                if !more_within(k, 1, base, 12) {
                    break;
                }
            }
        }
        Ok(())
    }

    /// Writes the run `i..j` of `b` (within 32 columns) as [`Evt3Writer::with_full_vector_groups`]
    /// says: one event as `EVT_ADDR_X`, more as one whole group.
    fn write_group(&mut self, b: &EventBatch, i: usize, j: usize) -> Result<()> {
        let e = b.get(i);
        if j - i < 2 {
            return self.write_event(&e);
        }
        self.prepare(&e)?;
        self.check_vector_rest(b, i, i + 1, j)?;
        let mask = b.x[i..j].iter().fold(0u32, |m, &x| m | 1 << (x - e.x));
        self.put(word::VECT_BASE_X, u32::from(e.x) | polarity_bit(e.polarity))?;
        self.put(word::VECT_12, mask & 0xFFF)?;
        self.put(word::VECT_12, (mask >> 12) & 0xFFF)?;
        self.put(word::VECT_8, (mask >> 24) & 0xFF)?;
        self.summary.items += (j - i) as u64;
        Ok(())
    }

    /// Flushes and returns the sink and what was written.
    pub fn finish(self) -> Result<(W, WriteSummary)> {
        self.out.finish_with(self.summary)
    }
}

/// The EVT 3.0 words of `batch` alone, without a file's `%` header: what an
/// `event_camera_msgs/EventPacket` with encoding `evt3` carries. Each packet starts its own time
/// and row words, so it decodes on its own.
///
/// # Errors
/// An event the format cannot hold (see [`Evt3Writer`]).
pub fn packet_words(batch: &EventBatch, resolution: Resolution) -> Result<Vec<u8>> {
    let header = raw_header("3.0", "EVT3", resolution).len();
    let mut w = Evt3Writer::new(Vec::new(), "an EVT 3.0 packet", resolution)?;
    w.write_batch(batch)?;
    let (bytes, _) = w.finish()?;
    Ok(bytes.get(header..).map(<[u8]>::to_vec).unwrap_or_default())
}

/// The polarity bit of an `EVT_ADDR_X` or `VECT_BASE_X` payload for a (checked) polarity of ±1.
fn polarity_bit(polarity: i8) -> u32 {
    if polarity > 0 { POLARITY_BIT } else { 0 }
}

impl<W: Write> crate::EventWriter for Evt3Writer<W> {
    fn write_event(&mut self, e: &Event) -> Result<()> {
        Evt3Writer::write_event(self, e)
    }

    fn write_batch(&mut self, b: &EventBatch) -> Result<()> {
        Evt3Writer::write_batch(self, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::fast_vs_checked::{assert_same, decode_all, options};
    use proptest::prelude::*;

    /// A word: mostly the ordinary kinds, with coordinates a little past the 40x30 sensor, times
    /// that mostly rise (and sometimes step back or wrap), and a few rare or unknown types.
    fn word() -> impl Strategy<Value = u16> {
        let w = |kind: u8, payload: u32| (u16::from(kind) << 12) | (payload & 0xFFF) as u16;
        prop_oneof![
            4 => (0u32..34, any::<bool>()).prop_map(move |(y, s)| w(word::ADDR_Y, y | u32::from(s) << 11)),
            8 => (0u32..44, any::<bool>()).prop_map(move |(x, p)| w(word::ADDR_X, x | u32::from(p) << 11)),
            3 => (0u32..44, any::<bool>()).prop_map(move |(x, p)| w(word::VECT_BASE_X, x | u32::from(p) << 11)),
            3 => any::<u16>().prop_map(move |v| w(word::VECT_12, u32::from(v))),
            2 => any::<u8>().prop_map(move |v| w(word::VECT_8, u32::from(v))),
            4 => (0u32..4096).prop_map(move |t| w(word::TIME_LOW, t)),
            2 => (0u32..4096).prop_map(move |t| w(word::TIME_HIGH, t)),
            1 => prop_oneof![
                Just(word::CONTINUED_4),
                Just(word::CONTINUED_12),
                Just(word::OTHERS),
                Just(word::EXT_TRIGGER),
                Just(0x1),
                Just(0x9),
            ]
            .prop_map(move |k| w(k, 5)),
        ]
    }

    /// A word, or now and then a whole `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group (the fast
    /// path takes those at once), with bits that may run past the sensor.
    fn piece() -> impl Strategy<Value = Vec<u16>> {
        let w = |kind: u8, payload: u32| (u16::from(kind) << 12) | (payload & 0xFFF) as u16;
        prop_oneof![
            30 => word().prop_map(|w| vec![w]),
            1 => (0u32..44, any::<bool>(), any::<u16>(), any::<u16>(), any::<u8>(), 0u32..4)
                .prop_map(move |(x, p, a, b, c, sparse)| {
                    // Mostly a few valid bits, as in recordings; sometimes dense ones.
                    let thin = |v: u32| if sparse > 0 { v & v >> 3 & v >> 7 } else { v };
                    vec![
                        w(word::VECT_BASE_X, x | u32::from(p) << 11),
                        w(word::VECT_12, thin(u32::from(a))),
                        w(word::VECT_12, thin(u32::from(b))),
                        w(word::VECT_8, thin(u32::from(c))),
                    ]
                }),
        ]
    }

    /// Time words in order, so that long runs stay on the fast path.
    fn ordered(words: Vec<u16>) -> Vec<u8> {
        let (mut high, mut low) = (0u32, 0u32);
        let mut out = Vec::new();
        for (i, w) in words.into_iter().enumerate() {
            let w = match (w >> 12) as u8 {
                word::TIME_LOW if i % 7 != 0 => {
                    low = (low + u32::from(w & 3)).min(0xFFF);
                    (u16::from(word::TIME_LOW) << 12) | low as u16
                }
                word::TIME_HIGH if i % 11 != 0 => {
                    high = (high + 1) & 0xFFF;
                    (u16::from(word::TIME_HIGH) << 12) | high as u16
                }
                _ => w,
            };
            out.extend_from_slice(&w.to_le_bytes());
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]
        /// The fast path gives what the checked path gives, word for word: the same events,
        /// statistics and error, whatever the requests' sizes and the buffers' boundaries.
        #[test]
        fn the_fast_path_matches_the_checked_one(
            words in prop::collection::vec(piece(), 0..3000).prop_map(|p| p.concat()),
            max in 1usize..5000,
            piece in prop::sample::select(vec![2usize, 7, 64, 1 << 20]),
            clamp in any::<bool>(),
            skip_unknown in any::<bool>(),
        ) {
            let opts = options(clamp, skip_unknown);
            let bytes = ordered(words);
            let mut d = Evt3Decoder::default();
            let fast = decode_all(&bytes, max, piece, &opts, |b, at, sink, out| d.decode(b, at, sink, out));
            let mut d = Evt3Decoder::default();
            let checked =
                decode_all(&bytes, max, piece, &opts, |b, at, sink, out| d.decode_checked(b, at, sink, out));
            assert_same(&fast, &checked)?;
        }
    }

    /// Readers that keep the last `TIME_LOW` across a `TIME_HIGH` (Prophesee's, evlib) read the
    /// writer's times too: every `TIME_HIGH` is followed by a `TIME_LOW` before the next event.
    #[test]
    fn every_time_high_is_followed_by_a_time_low_before_an_event() {
        let mut w = Evt3Writer::new(Vec::new(), "mem", Resolution::new(8, 8)).expect("writer");
        // Times that cross TIME_HIGH boundaries (4,096 us), some landing on a low part of 0 after
        // a non-zero one.
        for (k, t_us) in [
            5u64,
            4_095,
            4_096 + 7,
            2 * 4_096,
            3 * 4_096 + 1,
            3 * 4_096 + 1,
            40 * 4_096,
        ]
        .into_iter()
        .enumerate()
        {
            let e = Event {
                t_ns: (t_us * 1000) as i64,
                x: (k % 8) as u16,
                y: 1,
                polarity: 1,
            };
            w.write_event(&e).expect("write");
        }
        let (bytes, _) = w.finish().expect("finish");
        let kinds: Vec<u8> = bytes
            .chunks_exact(2)
            .map(|c| (u16::from_le_bytes([c[0], c[1]]) >> 12) as u8)
            .collect();
        let mut pending_high = false;
        for k in kinds {
            match k {
                word::TIME_HIGH => pending_high = true,
                word::TIME_LOW => pending_high = false,
                word::ADDR_X | word::VECT_BASE_X => {
                    assert!(!pending_high, "an event right after TIME_HIGH")
                }
                _ => {}
            }
        }
    }

    #[test]
    fn a_stream_in_packets_decodes_as_the_whole_and_keeps_its_state_across_them() {
        let mut batch = EventBatch::empty(40, 30, 0, 10_000_000, 0);
        for i in 0..300i64 {
            batch.push(Event {
                t_ns: 1_000 * (i * 7 + i % 5),
                x: (i * 13 % 40) as u16,
                y: (i * 7 % 30) as u16,
                polarity: if i % 3 == 0 { 1 } else { -1 },
            });
        }
        let words = packet_words(&batch, Resolution::new(40, 30)).expect("words");
        // Cut into packets at arbitrary word boundaries: rows and times set in one packet
        // serve the next.
        let mut stream = Evt3Stream::new(
            "ros2:/events",
            Resolution::new(40, 30),
            &crate::ReadOptions::default(),
        );
        let mut out = EventBatch::empty(40, 30, 0, 0, 0);
        for piece in words.chunks(2 * 7) {
            stream.decode(piece, &mut out).expect("packet");
        }
        assert_eq!(out.t_ns, batch.t_ns);
        assert_eq!(
            (out.x.clone(), out.y.clone()),
            (batch.x.clone(), batch.y.clone())
        );
        assert_eq!(out.polarity, batch.polarity);
        let e = stream
            .decode(&[1, 2, 3], &mut out)
            .expect_err("odd")
            .to_string();
        assert!(e.contains("ros2:/events") && e.contains("3 bytes"), "{e}");
    }

    /// A packet may hold at most `max_events_per_packet` events: one more is an error naming the
    /// limit, found within a slice of the packet (the memory taken is bounded by the limit, not by
    /// the packet); a packet larger than a slice decodes as the whole.
    #[test]
    fn a_packet_holds_at_most_its_limit_of_events() {
        let res = Resolution::new(320, 240);
        let mut batch = EventBatch::empty(320, 240, 0, 10_000_000, 0);
        // Full rows: 320 events at each of 5,000 instants, in vector words.
        for t in 0..5_000i64 {
            for x in 0..320u16 {
                batch.push(Event {
                    t_ns: 1_000 * t,
                    x,
                    y: (t % 240) as u16,
                    polarity: 1,
                });
            }
        }
        let words = packet_words(&batch, res).expect("words");
        assert!(
            words.len() > 2 * STREAM_SLICE_BYTES,
            "{} bytes",
            words.len()
        );
        let opts = |max| crate::ReadOptions {
            max_events_per_packet: max,
            ..crate::ReadOptions::default()
        };
        let mut out = EventBatch::empty(320, 240, 0, 0, 0);
        let n = Evt3Stream::new("p", res, &opts(batch.len()))
            .decode(&words, &mut out)
            .expect("exactly the limit");
        assert_eq!((n, &out.x, &out.t_ns), (batch.len(), &batch.x, &batch.t_ns));
        // Over the limit: what was decoded up to the slice that crossed it is kept (as with any
        // error of a stream), then the error, and the stream is over.
        let mut out = EventBatch::empty(320, 240, 0, 0, 0);
        let mut stream = Evt3Stream::new("ros2:/events", res, &opts(10_000));
        let n = stream
            .decode(&words, &mut out)
            .expect("the events before the error");
        assert!(
            n > 10_000 && n <= 10_000 + 6 * STREAM_SLICE_BYTES,
            "{n} events held"
        );
        let e = stream
            .decode(&words, &mut out)
            .expect_err("over the limit")
            .to_string();
        assert!(
            e.starts_with("ros2:/events: byte ") && e.contains("more than 10000 events"),
            "{e}"
        );
        assert_eq!(out.len(), n);
    }

    #[test]
    fn a_clock_near_the_end_of_i64_leaves_the_fast_path() {
        let mut d = Evt3Decoder {
            high: Some(0),
            y: Some(0),
            wraps: (i64::MAX / 1000) as u64 >> 24,
            ..Evt3Decoder::default()
        };
        let x = ((u16::from(word::ADDR_X) << 12) | 1).to_le_bytes();
        let mut out = EventBatch::default();
        assert_eq!(d.decode_fast(&x, 40, &mut out, 100), 0);
        d.wraps -= 1;
        assert_eq!(d.decode_fast(&x, 40, &mut out, 100), 2);
        assert_eq!(out.x, [1]);
    }

    /// A base column carried (by a long run of vector words) to just below `u32::MAX`: the next
    /// vector's columns would wrap back onto the sensor (x 0 to 7). Both paths refuse them, naming
    /// the saturated column, and deliver none.
    #[test]
    fn vector_columns_past_u32_max_are_out_of_bounds_not_wrapped() {
        let state = Evt3Decoder {
            high: Some(0),
            y: Some(0),
            base_x: Some(u32::MAX - 3),
            base_on: true,
            ..Evt3Decoder::default()
        };
        // VECT_12 with bits 4..=11 valid: columns base + 4 ..= base + 11, past u32::MAX.
        let vect = ((u16::from(word::VECT_12) << 12) | 0xFF0).to_le_bytes();
        let opts = crate::ReadOptions::default();
        let mut d = state;
        let fast = decode_all(&vect, 100, 64, &opts, |b, at, sink, out| {
            d.decode(b, at, sink, out)
        });
        let mut d = state;
        let checked = decode_all(&vect, 100, 64, &opts, |b, at, sink, out| {
            d.decode_checked(b, at, sink, out)
        });
        for (events, _, error) in [fast, checked] {
            assert!(
                events.is_empty(),
                "wrapped columns delivered: {:?}",
                events.x
            );
            let e = error.expect("an error");
            assert!(
                e.contains("byte 0") && e.contains("(4294967295, 0)") && e.contains("40x30"),
                "{e}"
            );
        }
        // The base itself saturates instead of wrapping (a vector word without valid bits).
        let empty = (u16::from(word::VECT_12) << 12).to_le_bytes();
        let mut d = state;
        let (events, _, error) = decode_all(&empty, 100, 64, &opts, |b, at, sink, out| {
            d.decode_checked(b, at, sink, out)
        });
        assert!(events.is_empty() && error.is_none(), "{error:?}");
        assert_eq!(d.base_x, Some(u32::MAX));
    }
}
